"""The rescue measurement (DESIGN §5 rule 3): envelope, detection and takeover search on synthetic data, then once
on a scenario."""

import numpy as np
import pytest

from lerobot_kvm.envs.env import KvmObsolescenceEnv
from lerobot_kvm.evaluation.rescue import Envelope, last_rescue_step
from lerobot_kvm.evaluation.suite_check import LATENCIES, rescue, run_episode


def ramp_runs(n: int, steps: int, seed: int = 0) -> list[np.ndarray]:
    """Runs of one channel that ramps up from step 10, with a little noise and a start that varies by a step."""
    rng = np.random.default_rng(seed)
    runs = []
    for _ in range(n):
        t = np.arange(steps) - rng.integers(-1, 2)
        runs.append((np.clip(t - 10, 0, None) * 0.5 + rng.normal(0, 0.05, steps))[:, None])
    return runs


def test_envelope_holds_runs_like_its_own_and_flags_a_departure():
    envelope = Envelope.fit(ramp_runs(20, 30))
    assert all(envelope.exit_step(run) is None for run in ramp_runs(20, 30, seed=1))
    departed = ramp_runs(1, 30, seed=2)[0]
    departed[17:] += 8.0  # e.g. a force that jumps once squeezing starts
    assert envelope.exit_step(departed) == 17


def test_envelope_bounds_come_from_the_runs_still_going_and_the_last_step_beyond_them():
    short = [np.zeros((5, 1)), np.zeros((5, 1))]
    long = np.concatenate([np.zeros((5, 1)), np.full((3, 1), 10.0)])  # the only run still going after step 4
    envelope = Envelope.fit([*short, long], window=0, stretch=0.0, margin=0.0, floor=0.01)
    assert envelope.high[2, 0] == pytest.approx(0.01) and envelope.low[6, 0] == pytest.approx(9.99)
    assert envelope.exit_step(np.full((12, 1), 10.0)) == 0  # 10 at the start is outside
    assert envelope.exit_step(np.concatenate([np.zeros((5, 1)), np.full((7, 1), 10.0)])) is None


def test_envelope_widens_by_the_window_in_time():
    runs = [np.concatenate([np.zeros((10, 1)), np.ones((10, 1))]) for _ in range(3)]
    envelope = Envelope.fit(runs, window=2, stretch=0.0, margin=0.0, floor=0.0)
    early = np.concatenate([np.zeros((8, 1)), np.ones((12, 1))])  # the same rise two steps early
    assert envelope.exit_step(early) is None
    assert envelope.exit_step(np.concatenate([np.zeros((7, 1)), np.ones((13, 1))])) == 7


@pytest.mark.parametrize("last", [None, 0, 3, 11])
def test_last_rescue_step_bisects_to_the_latest_switch_that_still_works(last: int | None):
    tried: list[int] = []

    def rescues(step: int) -> bool:
        tried.append(step)
        return last is not None and step <= last

    assert last_rescue_step(rescues, harm_step=12, known={}) == last
    assert len(tried) <= 5 and len(set(tried)) == len(tried)


def test_last_rescue_step_starts_from_what_is_known():
    def rescues(step: int) -> bool:
        raise AssertionError("nothing left to try")

    assert last_rescue_step(rescues, harm_step=12, known={7: True, 8: False}) == 7


def test_rescue_on_a_scenario_reports_every_measure():
    env = KvmObsolescenceEnv(task="sponge")
    seeds = [0, 1]
    shifted = [run_episode(env, "shifted", env.scenario.info.prior_skill, s) for s in seeds]
    result = rescue(env, seeds, shifted)
    env.close()
    assert result["false_alarm"] in (0.0, 0.5, 1.0)
    assert result["rescue_episodes"]["harm_steps"] == [e.steps for e in shifted]  # the light grasp drops it
    for latency in LATENCIES:
        assert 0.0 <= result[f"rescue_{latency}"] <= 1.0
    for detected, last in zip(
        result["rescue_episodes"]["detection_steps"], result["rescue_episodes"]["last_rescue_steps"], strict=True
    ):
        assert detected is None or last is None or 0 <= last < shifted[0].steps + 5
