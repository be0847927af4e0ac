import numpy as np
import pytest

from lerobot_kvm.envs.env import KvmObsolescenceEnv

TASK = "plate"


def fold_degrees(env) -> float:
    return abs(float(np.degrees(env.data.joint("plate_fold").qpos[0])))


@pytest.mark.parametrize("seed", [0, 1])
def test_rim_lift_carries_a_sturdy_plate_and_folds_a_paper_one(run_expert, seed):
    run = run_expert(TASK, "prior", "rim_lift", seed)
    info, env = run.info, run.env
    assert info["is_success"] and not info["catastrophe"]
    assert fold_degrees(env) < 3
    run = run_expert(TASK, "shifted", "rim_lift", seed)
    info, env = run.info, run.env
    assert info["catastrophe"] and info["catastrophe_kind"] == "drop"
    assert not info["is_success"] and fold_degrees(env) > 20  # the paper plate folded at the grip
    assert env.data.body("cake").xpos[2] < env.data.body("plate_rim").xpos[2]  # the cake slid off


@pytest.mark.parametrize("variant", ["prior", "shifted"])
def test_support_lift_carries_either_plate_flat(run_expert, variant):
    run = run_expert(TASK, variant, "support_lift")
    info, env = run.info, run.env
    assert info["is_success"] and not info["catastrophe"]
    assert fold_degrees(env) < 5


def test_paper_plate_weighs_far_less_on_the_wrist(run_expert):
    """Rule 3: lifted from underneath, the sturdy plate loads the wrist far more than the paper one."""
    run = run_expert(TASK, "prior", "support_lift")
    sturdy = run.observations[-1]["context"]
    run = run_expert(TASK, "shifted", "support_lift")
    paper = run.observations[-1]["context"]
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
