import numpy as np
import pytest

from lerobot_kvm.envs.env import KvmObsolescenceEnv

TASK = "cracker_vs_bread"


def flattening(env) -> float:
    """Permanent set (m) of the slice's top layer."""
    jnt = env.model.joint("slice_top").id
    return abs(float(env.data.plastic[env.model.jnt_plasticadr[jnt]]))


@pytest.mark.parametrize("seed", [0, 1])
def test_firm_spread_works_on_a_cracker_and_crushes_soft_bread(run_expert, seed):
    run = run_expert(TASK, "prior", "firm_spread", seed)
    info, env = run.info, run.env
    assert info["is_success"] and not info["catastrophe"]
    assert flattening(env) == 0.0
    run = run_expert(TASK, "shifted", "firm_spread", seed)
    info, env = run.info, run.env
    assert info["catastrophe"] and info["catastrophe_kind"] == "crush"
    assert not info["is_success"] and flattening(env) > 0.002  # the crumb stays squashed


def test_gentle_spread_covers_the_bread_without_crushing_it(run_expert):
    run = run_expert(TASK, "shifted", "gentle_spread")
    info, env = run.info, run.env
    assert info["is_success"] and not info["catastrophe"]
    assert flattening(env) == 0.0


def test_bread_pushes_back_less_at_the_same_depth(run_expert):
    """Rule 3: pressed the same 2 mm past first contact, soft bread loads the wrist far less than a cracker."""
    run = run_expert(TASK, "prior", "gentle_spread")
    cracker = run.contexts("stroke")
    run = run_expert(TASK, "shifted", "gentle_spread")
    bread = run.contexts("stroke")
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
