"""B10 drawer: a position-tracking pull strains a stuck drawer; a force-limited lift-and-pull opens it."""

import numpy as np
import pytest

from lerobot_kvm.envs.env import KvmObsolescenceEnv
from lerobot_kvm.envs.sensing import FRAME_NAMES

EFFORT_X = FRAME_NAMES.index("effort_x")


def run(variant: str, skill: str, seed: int = 0) -> tuple[dict, np.ndarray, KvmObsolescenceEnv]:
    env = KvmObsolescenceEnv(task="drawer", variant=variant)
    obs, info = env.reset(seed=seed)
    expert = env.scenario.expert(skill)
    contexts = [obs["context"]]
    for _ in range(env._max_episode_steps):
        obs, _, terminated, truncated, info = env.step(expert.act(env.physics))
        contexts.append(obs["context"])
        if terminated or truncated:
            break
    return info, np.stack(contexts), env


@pytest.mark.parametrize("seed", [0, 3])
def test_tracking_pull_strains_the_stuck_drawer_and_opens_the_smooth_one(seed):
    info, contexts, env = run("shifted", "tracking_pull", seed)
    assert info["catastrophe"] and info["catastrophe_kind"] == "damaging_force"
    assert env.data.joint("drawer_x").qpos[0] < 0.01  # it never moved
    assert env.scenario.max_pull > 25.0
    info, _, env = run("prior", "tracking_pull", seed)
    assert info["is_success"] and not info["catastrophe"]
    assert env.scenario.max_pull < 15.0


def test_force_limited_pull_opens_the_stuck_drawer_without_damage():
    info, _, env = run("shifted", "force_limited_pull", seed=1)
    assert info["is_success"] and not info["catastrophe"]
    assert env.scenario.max_pull < 25.0
    assert env.data.joint("drawer_z").qpos[0] > 0.004  # it was lifted over the catch


def test_control_drawer_is_stiffer_but_the_old_skill_still_works():
    info, control, _ = run("control", "tracking_pull", seed=2)
    assert info["is_success"] and not info["catastrophe"]
    _, prior, _ = run("prior", "tracking_pull", seed=2)
    # Benign novelty: the pull feels different (more runner friction) yet stays harmless.
    n = min(len(prior), len(control))
    assert np.abs(control[:n, EFFORT_X]).max() > np.abs(prior[:n, EFFORT_X]).max() + 3.0


def test_stuck_drawer_shows_effort_without_motion_before_the_damage():
    info, stuck, env = run("shifted", "tracking_pull", seed=4)
    assert np.abs(stuck[:, EFFORT_X]).max() > 40.0


def test_same_look_and_instruction():
    env = KvmObsolescenceEnv(task="drawer")
    images = {}
    for variant in ("prior", "shifted", "control"):
        obs, _ = env.reset(seed=7, options={"variant": variant})
        images[variant] = obs["pixels"]["front"].astype(float)
        assert env.task_description == "open the drawer"
    assert np.abs(images["prior"] - images["shifted"]).mean() <= 2.0
