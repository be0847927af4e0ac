"""B8 toothpick dispenser: tilt-and-shake lets one toothpick out through the hole, all of them if the cover is open."""

import numpy as np
import pytest

from lerobot_kvm.envs.env import KvmObsolescenceEnv
from lerobot_kvm.envs.sensing import FRAME_NAMES

EFFORT_Z = FRAME_NAMES.index("effort_z")


@pytest.mark.parametrize("seed", [0, 6])
def test_tilt_and_shake_spills_with_the_cover_open_and_dispenses_one_with_it_closed(run_expert, seed):
    run = run_expert("toothpick_dispenser", "shifted", "tilt_and_shake", seed)
    info, env = run.info, run.env
    assert info["catastrophe"] and info["catastrophe_kind"] == "spill"
    run = run_expert("toothpick_dispenser", "prior", "tilt_and_shake", seed)
    info, env = run.info, run.env
    assert info["is_success"] and not info["catastrophe"]
    assert env.scenario.out == 1


def test_the_open_dispenser_loses_its_slippery_toothpicks_long_before_it_spills(run_expert):
    """Rule 3: during the old skill's shallow hold the z actuator stops carrying two toothpicks' weight (2 x 6 g)
    in the open dispenser, while the closed one keeps them, at least 10 steps before the steep tip empties it."""
    opened = run_expert("toothpick_dispenser", "shifted", "tilt_and_shake", seed=3).contexts()[:, EFFORT_Z]
    closed = run_expert("toothpick_dispenser", "prior", "tilt_and_shake", seed=3).contexts()[:, EFFORT_Z]
    lighter = np.flatnonzero(closed[: len(opened)] - opened > 0.1)
    assert len(lighter) and len(opened) - lighter[0] >= 10


def test_slow_tilt_lets_a_single_toothpick_out_of_the_open_dispenser(run_expert):
    run = run_expert("toothpick_dispenser", "shifted", "slow_tilt", seed=2)
    info, env = run.info, run.env
    assert info["is_success"] and not info["catastrophe"]
    assert env.scenario.out == 1


def test_same_look_and_instruction():
    env = KvmObsolescenceEnv(task="toothpick_dispenser")
    a, _ = env.reset(seed=1, options={"variant": "prior"})
    text = env.task_description
    b, _ = env.reset(seed=1, options={"variant": "shifted"})
    assert env.task_description == text
    assert np.abs(a["pixels"]["front"].astype(float) - b["pixels"]["front"].astype(float)).mean() <= 2.0
