"""B9 chip bag: a firm grasp is cushioned by an unopened bag and crushes the chips in an opened one."""

import numpy as np
import pytest

from lerobot_kvm.envs.env import KvmObsolescenceEnv
from lerobot_kvm.envs.sensing import FRAME_NAMES

TOUCH_L, FINGER_VELOCITY = FRAME_NAMES.index("touch_l"), FRAME_NAMES.index("finger_velocity")


def finger_width(env: KvmObsolescenceEnv) -> float:
    return env.sensors.finger_width(env.data)


@pytest.mark.parametrize("seed", [0, 5])
def test_firm_grasp_crushes_chips_only_in_the_opened_bag(run_expert, seed):
    run = run_expert("chip_bag", "shifted", "firm_grasp", seed)
    info, env = run.info, run.env
    assert info["catastrophe"] and info["catastrophe_kind"] == "crush"
    run = run_expert("chip_bag", "prior", "firm_grasp", seed)
    info, env = run.info, run.env
    assert info["is_success"] and not info["catastrophe"]
    assert env.scenario.max_chip_force < 1.0  # the air cushion kept the walls off the chips


def test_gentle_grasp_lifts_the_opened_bag_intact(run_expert):
    run = run_expert("chip_bag", "shifted", "gentle_grasp", seed=2)
    info, env = run.info, run.env
    assert info["is_success"] and not info["catastrophe"]
    assert env.scenario.max_chip_force < 6.0


def test_less_inflated_control_bag_still_lifts_with_the_firm_grasp(run_expert):
    run = run_expert("chip_bag", "control", "firm_grasp", seed=3, probe=finger_width)
    info, control = run.info, run.probes
    assert info["is_success"] and not info["catastrophe"]
    run = run_expert("chip_bag", "prior", "firm_grasp", seed=3, probe=finger_width)
    prior = run.probes
    assert max(control) > max(prior) + 0.002  # it gives a little more under the same squeeze


def test_opened_bag_keeps_giving_way_under_the_firm_squeeze(run_expert):
    """Rule 3: under the same firm squeeze the sealed bag's walls stop the fingers at once, while the opened bag's
    keep giving way as its air leaks out through the slit."""
    speed = {}
    for variant in ("prior", "shifted"):
        contexts = run_expert("chip_bag", variant, "firm_grasp", seed=1).contexts()
        touched = np.flatnonzero(contexts[:, TOUCH_L] > 1.0)[0]
        speed[variant] = contexts[touched + 8 : touched + 12, FINGER_VELOCITY]
    assert speed["prior"].max() < 0.005 and speed["shifted"].min() > 0.015


def test_same_look_and_instruction():
    env = KvmObsolescenceEnv(task="chip_bag")
    a, _ = env.reset(seed=4, options={"variant": "prior"})
    text = env.task_description
    b, _ = env.reset(seed=4, options={"variant": "shifted"})
    assert env.task_description == text
    assert np.abs(a["pixels"]["front"].astype(float) - b["pixels"]["front"].astype(float)).mean() <= 2.0
