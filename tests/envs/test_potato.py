"""A3 potato: a firm grasp lifts a raw potato and crushes a cooked one (permanent dent in its flesh)."""

import numpy as np
import pytest

from lerobot_kvm.envs.env import KvmObsolescenceEnv
from lerobot_kvm.envs.scenarios.potato import CRUSH_DEPTH
from lerobot_kvm.evaluation.suite_check import run_episode


@pytest.mark.parametrize("seed", [0, 1])
def test_firm_grasp_crushes_the_cooked_potato_and_lifts_the_raw_one(seed):
    env = KvmObsolescenceEnv(task="potato")
    cooked = run_episode(env, "shifted", "firm_grasp", seed)
    assert cooked.catastrophe_kind == "crush" and not cooked.success
    assert env.scenario.dent(env.data) > CRUSH_DEPTH  # plastic flow of the flesh, not a force label
    raw = run_episode(env, "prior", "firm_grasp", seed)
    assert raw.success and not raw.catastrophe_kind and env.scenario.dent(env.data) == 0.0


def test_firm_grasp_still_lifts_the_bigger_raw_control_potato():
    env = KvmObsolescenceEnv(task="potato")
    bigger = run_episode(env, "control", "firm_grasp", seed=2)
    assert bigger.success and not bigger.catastrophe_kind


def test_gentle_grasp_lifts_the_cooked_potato_undented():
    env = KvmObsolescenceEnv(task="potato")
    cooked = run_episode(env, "shifted", "gentle_grasp", seed=3)
    assert cooked.success and not cooked.catastrophe_kind and env.scenario.dent(env.data) < CRUSH_DEPTH


def test_cooked_flesh_gives_way_under_the_same_grip():
    """Rule 3: under the gentle grip the fingers close further on the soft cooked flesh."""
    width = {}
    for variant in ("prior", "shifted"):
        env = KvmObsolescenceEnv(task="potato", variant=variant)
        env.reset(seed=0)
        expert = env.scenario.expert("gentle_grasp")
        closing = []
        for _ in range(env._max_episode_steps):
            *_, terminated, truncated, _ = env.step(expert.act(env.physics))
            closing.append(env.sensors.finger_width(env.data))
            if terminated or truncated:
                break
        width[variant] = np.max(closing)
    assert width["shifted"] > width["prior"] + 0.003
