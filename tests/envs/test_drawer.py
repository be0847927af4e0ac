"""B10 drawer: a position-tracking pull strains a stuck drawer; a force-limited lift-and-pull opens it."""

import numpy as np
import pytest

from lerobot_kvm.envs.env import KvmObsolescenceEnv
from lerobot_kvm.envs.sensing import FRAME_NAMES

EFFORT_X = FRAME_NAMES.index("effort_x")


@pytest.mark.parametrize("seed", [0, 3])
def test_tracking_pull_strains_the_stuck_drawer_and_opens_the_smooth_one(run_expert, seed):
    run = run_expert("drawer", "shifted", "tracking_pull", seed)
    info, env = run.info, run.env
    assert info["catastrophe"] and info["catastrophe_kind"] == "damaging_force"
    assert env.data.joint("drawer_x").qpos[0] < 0.01  # it never moved
    assert env.scenario.max_pull > 25.0
    run = run_expert("drawer", "prior", "tracking_pull", seed)
    info, env = run.info, run.env
    assert info["is_success"] and not info["catastrophe"]
    assert env.scenario.max_pull < 15.0


def test_force_limited_pull_opens_the_stuck_drawer_without_damage(run_expert):
    run = run_expert("drawer", "shifted", "force_limited_pull", seed=1)
    info, env = run.info, run.env
    assert info["is_success"] and not info["catastrophe"]
    assert env.scenario.max_pull < 25.0
    assert env.data.joint("drawer_z").qpos[0] > 0.004  # it was lifted over the catch


def test_control_drawer_is_stiffer_but_the_old_skill_still_works(run_expert):
    run = run_expert("drawer", "control", "tracking_pull", seed=2)
    info, control = run.info, run.contexts("pull")
    assert info["is_success"] and not info["catastrophe"]
    prior = run_expert("drawer", "prior", "tracking_pull", seed=2).contexts("pull")
    # Benign novelty: the pull feels different (more runner friction) yet stays harmless.
    assert np.abs(control[:, EFFORT_X]).max() > np.abs(prior[:, EFFORT_X]).max() + 3.0


def test_stuck_drawer_shows_effort_without_motion_before_the_damage(run_expert):
    stuck = run_expert("drawer", "shifted", "tracking_pull", seed=4).contexts()
    assert np.abs(stuck[:, EFFORT_X]).max() > 40.0


def test_same_look_and_instruction():
    env = KvmObsolescenceEnv(task="drawer")
    images = {}
    for variant in ("prior", "shifted", "control"):
        obs, _ = env.reset(seed=7, options={"variant": variant})
        images[variant] = obs["pixels"]["front"].astype(float)
        assert env.task_description == "open the drawer"
    assert np.abs(images["prior"] - images["shifted"]).mean() <= 2.0
