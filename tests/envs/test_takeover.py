"""Experts that take over a running episode (`Scenario.expert(skill, takeover=physics)`) from the state it is in."""

import numpy as np
import pytest

from lerobot_kvm.envs.env import KvmObsolescenceEnv


def run_with_switch(
    env: KvmObsolescenceEnv, prior: str, safe: str, step: int, seed: int = 0
) -> tuple[dict, dict, list[np.ndarray]]:
    """`prior`'s expert until `step`, then `safe`'s taking over; the last info, the taking-over expert's attributes
    as it was built and every action."""
    env.reset(seed=seed)
    expert, actions = env.scenario.expert(prior), []
    for t in range(env._max_episode_steps):
        if t == step:
            expert = env.scenario.expert(safe, takeover=env.physics)
            taker = expert.__dict__.copy()
        actions.append(expert.act(env.physics))
        _, _, terminated, truncated, info = env.step(actions[-1])
        if terminated or truncated:
            return info, taker, actions
    raise AssertionError("the episode did not end")


def test_takeover_at_the_reset_acts_like_a_fresh_expert():
    env = KvmObsolescenceEnv(task="potato", variant="prior")
    _, _, switched = run_with_switch(env, "firm_grasp", "firm_grasp", step=0)
    env.reset(seed=0)
    expert, fresh = env.scenario.expert("firm_grasp"), []
    for _ in switched:
        fresh.append(expert.act(env.physics))
        env.step(fresh[-1])
    np.testing.assert_array_equal(np.stack(switched), np.stack(fresh))
    env.close()


@pytest.mark.parametrize(
    ("task", "prior", "safe", "step", "phase"),
    [
        # The light grasp drops the soaked sponge once lifted (step ~44); the firm grasp taking over while the sponge
        # is in the fingers keeps it (no reopening), squeezes with its own force and lifts it.
        ("sponge", "light_grasp", "firm_grasp", 38, "close"),
        # Over the cooked potato before touching it: the gentle grasp descends from there.
        ("potato", "firm_grasp", "gentle_grasp", 20, "descend"),
    ],
)
def test_grasp_takeover_carries_on_from_the_grasps_state(task: str, prior: str, safe: str, step: int, phase: str):
    env = KvmObsolescenceEnv(task=task, variant="shifted")
    info, taker, _ = run_with_switch(env, prior, safe, step)
    assert taker["phase"] == phase
    assert info["is_success"] and not info["catastrophe"]
    env.close()


def test_tilt_takeover_carries_on_from_the_wrists_angle():
    env = KvmObsolescenceEnv(task="toothpick_dispenser", variant="prior")
    env.reset(seed=0)
    expert = env.scenario.expert("tilt_and_shake")
    for _ in range(10):
        env.step(expert.act(env.physics))
    pitch = env.physics.sensors.arm_position(env.data)[3]
    assert pitch < -0.3  # tipped well over by the old skill
    action = env.scenario.expert("slow_tilt", takeover=env.physics).act(env.physics)
    assert abs(action[3] - pitch) < 0.05  # not snapped back level
    env.close()
