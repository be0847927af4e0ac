import numpy as np
import pytest

from lerobot_kvm.envs.env import KvmObsolescenceEnv

TASK = "plate"


def run_expert(variant: str, skill: str, seed: int = 0):
    """Run a scripted expert; returns the last info, the env (open) and the last context."""
    env = KvmObsolescenceEnv(task=TASK, variant=variant)
    obs, info = env.reset(seed=seed)
    expert = env.scenario.expert(skill)
    for _ in range(env._max_episode_steps):
        obs, _, terminated, truncated, info = env.step(expert.act(env.physics))
        if terminated or truncated:
            break
    return info, env, obs["context"]


def fold_degrees(env) -> float:
    return abs(float(np.degrees(env.data.joint("plate_fold").qpos[0])))


@pytest.mark.parametrize("seed", [0, 1])
def test_rim_lift_carries_a_sturdy_plate_and_folds_a_paper_one(seed):
    info, env, _ = run_expert("prior", "rim_lift", seed)
    assert info["is_success"] and not info["catastrophe"]
    assert fold_degrees(env) < 3
    info, env, _ = run_expert("shifted", "rim_lift", seed)
    assert info["catastrophe"] and info["catastrophe_kind"] == "drop"
    assert not info["is_success"] and fold_degrees(env) > 20  # the paper plate folded at the grip
    assert env.data.body("cake").xpos[2] < env.data.body("plate_rim").xpos[2]  # the cake slid off


@pytest.mark.parametrize("variant", ["prior", "shifted"])
def test_support_lift_carries_either_plate_flat(variant):
    info, env, _ = run_expert(variant, "support_lift")
    assert info["is_success"] and not info["catastrophe"]
    assert fold_degrees(env) < 5


def test_paper_plate_weighs_far_less_on_the_wrist():
    """Rule 3: lifted from underneath, the sturdy plate loads the wrist far more than the paper one."""
    _, _, sturdy = run_expert("prior", "support_lift")
    _, _, paper = run_expert("shifted", "support_lift")
    assert np.linalg.norm(sturdy[:3]) - np.linalg.norm(paper[:3]) > 1.0


def test_a_different_plate_in_view_and_in_words():
    a = KvmObsolescenceEnv(task=TASK, variant="prior")
    b = KvmObsolescenceEnv(task=TASK, variant="shifted")
    obs_a, _ = a.reset(seed=6)
    obs_b, _ = b.reset(seed=6)
    assert set(obs_a) == {"pixels", "agent_pos", "context"}
    assert np.abs(obs_a["pixels"]["front"].astype(float) - obs_b["pixels"]["front"].astype(float)).mean() > 0
    assert "paper plate" in b.task_description and "paper" not in a.task_description
    with pytest.raises(ValueError, match="no skill"):
        a.scenario.expert("flip")
