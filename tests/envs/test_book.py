import numpy as np
import pytest

from lerobot_kvm.envs.env import KvmObsolescenceEnv

TASK = "book"


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


def cover_dent(env) -> float:
    """Permanent set (m) of the cover panel's plastic mount."""
    jnt = env.model.joint("book_back").id
    return abs(float(env.data.plastic[env.model.jnt_plasticadr[jnt]]))


@pytest.mark.parametrize("seed", [0, 1])
def test_quick_push_slides_the_hardcover_and_dents_the_paperback(seed):
    info, env, _ = run_expert("prior", "fast_push", seed)
    assert info["is_success"] and not info["catastrophe"]
    assert cover_dent(env) == 0.0
    info, env, _ = run_expert("shifted", "fast_push", seed)
    assert info["catastrophe"] and info["catastrophe_kind"] == "damage"
    assert not info["is_success"] and cover_dent(env) > 0.0005  # a real permanent deformation


def test_slow_push_slides_the_paperback_undamaged():
    info, env, _ = run_expert("shifted", "slow_push")
    assert info["is_success"] and not info["catastrophe"]
    assert cover_dent(env) == 0.0


def test_control_heavier_hardcover_still_takes_the_quick_push():
    info, env, _ = run_expert("control", "fast_push")
    assert info["is_success"] and not info["catastrophe"]


def test_hardcover_and_paperback_push_back_differently():
    """Rule 3: sliding the heavier hardcover loads the wrist along the push more than the paperback."""
    _, _, hard = run_expert("prior", "slow_push")
    _, _, soft = run_expert("shifted", "slow_push")
    assert hard[:, 0].mean() - soft[:, 0].mean() > 0.8


def test_a_different_book_in_view_and_in_words():
    a = KvmObsolescenceEnv(task=TASK, variant="prior")
    b = KvmObsolescenceEnv(task=TASK, variant="shifted")
    obs_a, _ = a.reset(seed=2)
    obs_b, _ = b.reset(seed=2)
    assert set(obs_a) == {"pixels", "agent_pos", "context"}
    assert np.abs(obs_a["pixels"]["front"].astype(float) - obs_b["pixels"]["front"].astype(float)).mean() > 0
    assert "paperback" in b.task_description and "hardcover" in a.task_description
    with pytest.raises(ValueError, match="no skill"):
        a.scenario.expert("throw")
