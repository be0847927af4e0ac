import numpy as np
import pytest

from lerobot_kvm.envs.env import KvmObsolescenceEnv

TASK = "paper_towel_roll"


def flattening(env) -> float:
    """Largest permanent set (m) of the paper layers' plastic mounts."""
    m, d = env.model, env.data
    return max(abs(float(d.plastic[m.jnt_plasticadr[m.joint(f"layers_{s}").id]])) for s in "lr")


@pytest.mark.parametrize("seed", [0, 1])
def test_firm_grasp_lifts_a_cored_roll_and_crushes_a_coreless_one(run_expert, seed):
    run = run_expert(TASK, "prior", "firm_grasp", seed)
    info, env = run.info, run.env
    assert info["is_success"] and not info["catastrophe"]
    assert flattening(env) == 0.0
    run = run_expert(TASK, "shifted", "firm_grasp", seed)
    info, env = run.info, run.env
    assert info["catastrophe"] and info["catastrophe_kind"] == "crush"
    assert not info["is_success"] and flattening(env) > 0.003  # permanent deformation


def test_gentle_grasp_lifts_the_coreless_roll_intact(run_expert):
    run = run_expert(TASK, "shifted", "gentle_grasp")
    info, env = run.info, run.env
    assert info["is_success"] and not info["catastrophe"]
    assert flattening(env) == 0.0


def test_control_heavier_roll_still_takes_the_firm_grasp(run_expert):
    info = run_expert(TASK, "control", "firm_grasp").info
    assert info["is_success"] and not info["catastrophe"]


def test_coreless_roll_gives_way_under_the_fingers(run_expert):
    """Rule 3: with the same gentle grip the fingers close much further on the coreless roll."""
    run = run_expert(TASK, "prior", "gentle_grasp")
    cored = run.observations[-1]["agent_pos"]
    run = run_expert(TASK, "shifted", "gentle_grasp")
    coreless = run.observations[-1]["agent_pos"]
    finger_width = 4
    assert coreless[finger_width] - cored[finger_width] > 0.005


def test_a_different_roll_in_view_and_in_words():
    a = KvmObsolescenceEnv(task=TASK, variant="prior")
    b = KvmObsolescenceEnv(task=TASK, variant="shifted")
    obs_a, _ = a.reset(seed=1)
    obs_b, _ = b.reset(seed=1)
    assert set(obs_a) == {"pixels", "agent_pos", "context"}
    assert np.abs(obs_a["pixels"]["front"].astype(float) - obs_b["pixels"]["front"].astype(float)).mean() > 0
    assert "coreless" in b.task_description and "coreless" not in a.task_description
    with pytest.raises(ValueError, match="no skill"):
        a.scenario.expert("squash")
