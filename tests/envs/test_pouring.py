import numpy as np
import pytest

from lerobot_kvm.envs.env import KvmObsolescenceEnv
from lerobot_kvm.envs.scenarios.pouring import BOWL_H, BOWL_IN

TASK = "pouring"


def drops_beside_the_bowl(env) -> int:
    scenario = env.scenario
    p = scenario.drop_positions(env.data)
    rel = np.abs(p[:, :2] - scenario.bowl)
    return int(((rel.max(axis=1) > BOWL_IN + 0.003) & (p[:, 2] < BOWL_H)).sum())


def test_quick_pour_empties_water_into_the_bowl(run_expert):
    run = run_expert(TASK, "prior", "quick_pour")
    info, env = run.info, run.env
    assert info["is_success"] and not info["catastrophe"]
    assert drops_beside_the_bowl(env) == 0


def test_quick_pour_spills_honey_beside_the_bowl(run_expert):
    run = run_expert(TASK, "shifted", "quick_pour")
    info, env = run.info, run.env
    assert info["catastrophe"] and info["catastrophe_kind"] == "spill"
    assert not info["is_success"] and drops_beside_the_bowl(env) >= 2


def test_slow_pour_empties_honey_into_the_bowl(run_expert):
    run = run_expert(TASK, "shifted", "slow_pour")
    info, env = run.info, run.env
    assert info["is_success"] and not info["catastrophe"]
    assert drops_beside_the_bowl(env) == 0


def test_honey_leaves_the_cup_more_slowly_than_water(run_expert):
    """Rule 3: a few steps into the quick pour the wrist still carries the honey, while the water is gone."""
    run = run_expert(TASK, "prior", "quick_pour")
    water = np.linalg.norm(run.contexts()[:, :3], axis=1)
    run = run_expert(TASK, "shifted", "quick_pour")
    honey = np.linalg.norm(run.contexts()[:, :3], axis=1)
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
