import numpy as np
import pytest

from lerobot_kvm.envs.env import KvmObsolescenceEnv

TASK = "paper_towel_roll"


def run_expert(variant: str, skill: str, seed: int = 0):
    """Run a scripted expert; returns the last info, the env (open) and the last proprio state."""
    env = KvmObsolescenceEnv(task=TASK, variant=variant)
    obs, info = env.reset(seed=seed)
    expert = env.scenario.expert(skill)
    for _ in range(env._max_episode_steps):
        obs, _, terminated, truncated, info = env.step(expert.act(env.physics))
        if terminated or truncated:
            break
    return info, env, obs["agent_pos"]


def flattening(env) -> float:
    """Largest permanent set (m) of the paper layers' plastic mounts."""
    m, d = env.model, env.data
    return max(abs(float(d.plastic[m.jnt_plasticadr[m.joint(f"layers_{s}").id]])) for s in "lr")


@pytest.mark.parametrize("seed", [0, 1])
def test_firm_grasp_lifts_a_cored_roll_and_crushes_a_coreless_one(seed):
    info, env, _ = run_expert("prior", "firm_grasp", seed)
    assert info["is_success"] and not info["catastrophe"]
    assert flattening(env) == 0.0
    info, env, _ = run_expert("shifted", "firm_grasp", seed)
    assert info["catastrophe"] and info["catastrophe_kind"] == "crush"
    assert not info["is_success"] and flattening(env) > 0.003  # permanent deformation


def test_gentle_grasp_lifts_the_coreless_roll_intact():
    info, env, _ = run_expert("shifted", "gentle_grasp")
    assert info["is_success"] and not info["catastrophe"]
    assert flattening(env) == 0.0


def test_control_heavier_roll_still_takes_the_firm_grasp():
    info, _, _ = run_expert("control", "firm_grasp")
    assert info["is_success"] and not info["catastrophe"]


def test_coreless_roll_gives_way_under_the_fingers():
    """Rule 3: with the same gentle grip the fingers close much further on the coreless roll."""
    _, _, cored = run_expert("prior", "gentle_grasp")
    _, _, coreless = run_expert("shifted", "gentle_grasp")
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
