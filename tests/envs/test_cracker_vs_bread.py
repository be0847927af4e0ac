import numpy as np
import pytest

from lerobot_kvm.envs.env import KvmObsolescenceEnv

TASK = "cracker_vs_bread"


def run_expert(variant: str, skill: str, seed: int = 0):
    """Run a scripted expert; returns the last info, the env (open) and the contexts while stroking."""
    env = KvmObsolescenceEnv(task=TASK, variant=variant)
    env.reset(seed=seed)
    expert = env.scenario.expert(skill)
    stroke = []
    for _ in range(env._max_episode_steps):
        obs, _, terminated, truncated, info = env.step(expert.act(env.physics))
        if expert.phase == "stroke":
            stroke.append(obs["context"])
        if terminated or truncated:
            break
    return info, env, np.array(stroke)


def flattening(env) -> float:
    """Permanent set (m) of the slice's top layer."""
    jnt = env.model.joint("slice_top").id
    return abs(float(env.data.plastic[env.model.jnt_plasticadr[jnt]]))


@pytest.mark.parametrize("seed", [0, 1])
def test_firm_spread_works_on_a_cracker_and_crushes_soft_bread(seed):
    info, env, _ = run_expert("prior", "firm_spread", seed)
    assert info["is_success"] and not info["catastrophe"]
    assert flattening(env) == 0.0
    info, env, _ = run_expert("shifted", "firm_spread", seed)
    assert info["catastrophe"] and info["catastrophe_kind"] == "crush"
    assert not info["is_success"] and flattening(env) > 0.002  # the crumb stays squashed


def test_gentle_spread_covers_the_bread_without_crushing_it():
    info, env, _ = run_expert("shifted", "gentle_spread")
    assert info["is_success"] and not info["catastrophe"]
    assert flattening(env) == 0.0


def test_bread_pushes_back_less_at_the_same_depth():
    """Rule 3: pressed the same 2 mm past first contact, soft bread loads the wrist far less than a cracker."""
    _, _, cracker = run_expert("prior", "gentle_spread")
    _, _, bread = run_expert("shifted", "gentle_spread")
    wrist_force_z = 2  # the surface pushing up on the tool lowers this reading
    assert bread[:, wrist_force_z].mean() - cracker[:, wrist_force_z].mean() > 0.4


def test_a_different_slice_in_view_and_in_words():
    a = KvmObsolescenceEnv(task=TASK, variant="prior")
    b = KvmObsolescenceEnv(task=TASK, variant="shifted")
    obs_a, _ = a.reset(seed=4)
    obs_b, _ = b.reset(seed=4)
    assert set(obs_a) == {"pixels", "agent_pos", "context"}
    assert np.abs(obs_a["pixels"]["front"].astype(float) - obs_b["pixels"]["front"].astype(float)).mean() > 0
    assert "bread" in b.task_description and "cracker" in a.task_description
    with pytest.raises(ValueError, match="no skill"):
        a.scenario.expert("stab")
