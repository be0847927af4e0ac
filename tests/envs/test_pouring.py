import numpy as np
import pytest

from lerobot_kvm.envs.env import KvmObsolescenceEnv
from lerobot_kvm.envs.scenarios.pouring import BOWL_H, BOWL_IN

TASK = "pouring"


def run_expert(variant: str, skill: str, seed: int = 0):
    """Run a scripted expert; returns the last info, the env (open) and the wrist-force magnitude per step."""
    env = KvmObsolescenceEnv(task=TASK, variant=variant)
    obs, info = env.reset(seed=seed)
    expert = env.scenario.expert(skill)
    force = [np.linalg.norm(obs["context"][:3])]
    for _ in range(env._max_episode_steps):
        obs, _, terminated, truncated, info = env.step(expert.act(env.physics))
        force.append(np.linalg.norm(obs["context"][:3]))
        if terminated or truncated:
            break
    return info, env, np.array(force)


def drops_beside_the_bowl(env) -> int:
    scenario = env.scenario
    p = scenario.drop_positions(env.data)
    rel = np.abs(p[:, :2] - scenario.bowl)
    return int(((rel.max(axis=1) > BOWL_IN + 0.003) & (p[:, 2] < BOWL_H)).sum())


def test_quick_pour_empties_water_into_the_bowl():
    info, env, _ = run_expert("prior", "quick_pour")
    assert info["is_success"] and not info["catastrophe"]
    assert drops_beside_the_bowl(env) == 0


def test_quick_pour_spills_honey_beside_the_bowl():
    info, env, _ = run_expert("shifted", "quick_pour")
    assert info["catastrophe"] and info["catastrophe_kind"] == "spill"
    assert not info["is_success"] and drops_beside_the_bowl(env) >= 2


def test_slow_pour_empties_honey_into_the_bowl():
    info, env, _ = run_expert("shifted", "slow_pour")
    assert info["is_success"] and not info["catastrophe"]
    assert drops_beside_the_bowl(env) == 0


def test_honey_leaves_the_cup_more_slowly_than_water():
    """Rule 3: a few steps into the quick pour the wrist still carries the honey, while the water is gone."""
    _, _, water = run_expert("prior", "quick_pour")
    _, _, honey = run_expert("shifted", "quick_pour")
    assert honey[26:32].mean() - water[26:32].mean() > 0.2


def test_a_different_liquid_in_view_and_in_words():
    a = KvmObsolescenceEnv(task=TASK, variant="prior")
    b = KvmObsolescenceEnv(task=TASK, variant="shifted")
    obs_a, _ = a.reset(seed=7)
    obs_b, _ = b.reset(seed=7)
    assert set(obs_a) == {"pixels", "agent_pos", "context"}
    assert np.abs(obs_a["pixels"]["front"].astype(float) - obs_b["pixels"]["front"].astype(float)).mean() > 0
    assert "honey" in b.task_description and "water" in a.task_description
    with pytest.raises(ValueError, match="no skill"):
        a.scenario.expert("splash")
