import numpy as np
import pytest

from lerobot_kvm.envs.env import KvmObsolescenceEnv

TASK = "soda_bottle"


def run_expert(variant: str, skill: str, seed: int = 0):
    """Run a scripted expert; returns the last info, the env (open) and the contexts seen while pushing."""
    env = KvmObsolescenceEnv(task=TASK, variant=variant)
    env.reset(seed=seed)
    expert = env.scenario.expert(skill)
    pushing = []
    for _ in range(env._max_episode_steps):
        obs, _, terminated, truncated, info = env.step(expert.act(env.physics))
        if expert.phase == "push":
            pushing.append(obs["context"])
        if terminated or truncated:
            break
    return info, env, np.array(pushing)


def bottle_tilt(env) -> float:
    return float(np.degrees(np.arccos(np.clip(env.data.body("bottle").xmat[8], -1, 1))))


@pytest.mark.parametrize("seed", [0, 1])
def test_fast_push_slides_a_full_bottle_and_knocks_an_empty_one_over(seed):
    info, env, _ = run_expert("prior", "fast_push", seed)
    assert info["is_success"] and not info["catastrophe"]
    assert bottle_tilt(env) < 8
    info, env, _ = run_expert("shifted", "fast_push", seed)
    assert info["catastrophe"] and info["catastrophe_kind"] == "tip_over"
    assert not info["is_success"] and bottle_tilt(env) > 40


def test_slow_low_push_moves_the_empty_bottle_upright():
    info, env, _ = run_expert("shifted", "slow_push")
    assert info["is_success"] and not info["catastrophe"]
    assert bottle_tilt(env) < 8


def test_control_heavier_bottle_still_takes_the_fast_push():
    info, _, _ = run_expert("control", "fast_push")
    assert info["is_success"] and not info["catastrophe"]


def test_full_and_empty_bottles_push_back_differently():
    """Rule 3: pushing the full bottle loads the wrist along the push far more than the empty one."""
    _, _, full = run_expert("prior", "slow_push")
    _, _, empty = run_expert("shifted", "slow_push")
    assert full[:, 0].mean() - empty[:, 0].mean() > 0.8


def test_a_different_bottle_in_view_and_in_words():
    a = KvmObsolescenceEnv(task=TASK, variant="prior")
    b = KvmObsolescenceEnv(task=TASK, variant="shifted")
    obs_a, _ = a.reset(seed=3)
    obs_b, _ = b.reset(seed=3)
    assert set(obs_a) == {"pixels", "agent_pos", "context"}
    diff = np.abs(obs_a["pixels"]["front"].astype(float) - obs_b["pixels"]["front"].astype(float)).mean()
    assert diff > 0
    assert a.task_description != b.task_description and "empty" in b.task_description
    with pytest.raises(ValueError, match="no skill"):
        a.scenario.expert("kick")
