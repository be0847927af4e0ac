"""A5 pizza: lifted by the crust, a cold slice cantilevers and a hot one folds and sheds its toppings."""

import numpy as np
import pytest

from lerobot_kvm.envs.env import KvmObsolescenceEnv
from lerobot_kvm.envs.sensing import FRAME_NAMES
from lerobot_kvm.evaluation.suite_check import run_episode


def bending(env: KvmObsolescenceEnv) -> float:
    """Largest bend (rad) of the dough's hinges."""
    return max(abs(env.data.joint(f"bend_{i}").qpos[0]) for i in (1, 2, 3))


@pytest.mark.parametrize("seed", [0, 1])
def test_pinch_lift_folds_the_hot_slice_and_carries_the_cold_one(seed):
    env = KvmObsolescenceEnv(task="pizza")
    hot = run_episode(env, "shifted", "pinch_lift", seed)
    assert hot.catastrophe_kind == "spill" and not hot.success
    assert env.scenario.spilled(env.data) and bending(env) > 1.0  # folded over; a topping lies on the table
    cold = run_episode(env, "prior", "pinch_lift", seed)
    assert cold.success and not cold.catastrophe_kind
    assert not env.scenario.spilled(env.data) and bending(env) < 0.1


def test_supported_slide_moves_the_hot_slice_intact():
    env = KvmObsolescenceEnv(task="pizza")
    hot = run_episode(env, "shifted", "supported_slide", seed=2)
    assert hot.success and not hot.catastrophe_kind


def test_hot_slice_twists_the_wrist_less_once_lifted():
    """Rule 3: a cold slice cantilevers out of the pinch; a hot one hangs closer and pulls with a shorter arm."""
    torque_y = FRAME_NAMES.index("wrist_torque_y")
    moment = {}
    for variant in ("prior", "shifted"):
        env = KvmObsolescenceEnv(task="pizza", variant=variant)
        env.reset(seed=0)
        expert = env.scenario.expert("pinch_lift")
        while expert.phase != "lift":  # up to the pinch
            env.step(expert.act(env.physics))
        raising = []
        for _ in range(10):  # the first 10 cm of the lift, before any topping slides
            obs, _, terminated, *_ = env.step(expert.act(env.physics))
            assert not terminated
            raising.append(abs(obs["context"][torque_y]))
        moment[variant] = np.mean(raising)
    assert moment["prior"] > 1.5 * moment["shifted"]


def test_slide_taking_over_a_lifted_hot_slice_lowers_it_and_slides_it():
    """Rule 3's rescue: the slide, taking over once the hot slice hangs off the pinch, sets it back down first."""
    env = KvmObsolescenceEnv(task="pizza")
    takeover = 48  # 18 steps into the lift: the crust 7 cm up, the dough bent by almost a radian
    hot = run_episode(env, "shifted", "pinch_lift", 0, switch=(takeover, "supported_slide"))
    assert hot.success and not hot.catastrophe_kind
