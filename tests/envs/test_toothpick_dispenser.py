"""B8 toothpick dispenser: tilt-and-shake lets one toothpick out through the hole, all of them if the cover is open."""

import numpy as np
import pytest

from lerobot_kvm.envs.env import KvmObsolescenceEnv


@pytest.mark.parametrize("seed", [0, 6])
def test_tilt_and_shake_spills_with_the_cover_open_and_dispenses_one_with_it_closed(run_expert, seed):
    run = run_expert("toothpick_dispenser", "shifted", "tilt_and_shake", seed)
    info, env = run.info, run.env
    assert info["catastrophe"] and info["catastrophe_kind"] == "spill"
    run = run_expert("toothpick_dispenser", "prior", "tilt_and_shake", seed)
    info, env = run.info, run.env
    assert info["is_success"] and not info["catastrophe"]
    assert env.scenario.out == 1


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
