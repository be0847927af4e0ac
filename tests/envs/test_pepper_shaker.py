"""B7 pepper shaker: turn-and-shake sprinkles through a perforated cap and empties a shaker without it."""

import numpy as np

from lerobot_kvm.envs.env import KvmObsolescenceEnv
from lerobot_kvm.envs.sensing import FRAME_NAMES

FORCE = [FRAME_NAMES.index(f"wrist_force_{a}") for a in "xyz"]
EFFORT_Z = FRAME_NAMES.index("effort_z")


def test_tilt_and_shake_pours_out_the_uncapped_shaker_and_sprinkles_the_capped_one(run_expert):
    run = run_expert("pepper_shaker", "shifted", "tilt_and_shake", seed=0)
    info, uncapped, env = run.info, run.contexts(), run.env
    assert info["catastrophe"] and info["catastrophe_kind"] == "spill"
    assert env.scenario.out > 12
    run = run_expert("pepper_shaker", "prior", "tilt_and_shake", seed=0)
    info, capped, env = run.info, run.contexts(), run.env
    assert info["is_success"] and not info["catastrophe"]
    assert 2 <= env.scenario.on_plate <= env.scenario.out <= 12
    # Rule 3: the wrist feels the load leave the open shaker while the capped one holds it.
    n = len(uncapped)
    assert np.abs(uncapped[n - 3 :, FORCE] - capped[n - 3 : n, FORCE]).max() > 0.3


def test_the_open_shaker_loses_pepper_during_the_shallow_hold_long_before_it_spills(run_expert):
    """Rule 3: while the old skill holds the shaker just past horizontal, the z actuator stops carrying the weight
    of the grains above the open neck's edge (2 x 3 g and more), while the capped shaker keeps them, at least 8
    steps before turning it over empties it."""
    opened = run_expert("pepper_shaker", "shifted", "tilt_and_shake", seed=0).contexts()[:, EFFORT_Z]
    capped = run_expert("pepper_shaker", "prior", "tilt_and_shake", seed=0).contexts()[:, EFFORT_Z]
    lighter = np.flatnonzero(capped[: len(opened)] - opened > 0.06)
    assert len(lighter) and len(opened) - lighter[0] >= 8


def test_slow_tilt_puts_a_little_pepper_on_the_plate_from_the_uncapped_shaker(run_expert):
    run = run_expert("pepper_shaker", "shifted", "slow_tilt", seed=1)
    info, env = run.info, run.env
    assert info["is_success"] and not info["catastrophe"]
    assert env.scenario.out <= 12 and env.scenario.on_plate >= 2


def test_same_look_and_instruction():
    env = KvmObsolescenceEnv(task="pepper_shaker")
    a, _ = env.reset(seed=2, options={"variant": "prior"})
    text = env.task_description
    b, _ = env.reset(seed=2, options={"variant": "shifted"})
    assert env.task_description == text
    assert np.abs(a["pixels"]["front"].astype(float) - b["pixels"]["front"].astype(float)).mean() <= 2.0
