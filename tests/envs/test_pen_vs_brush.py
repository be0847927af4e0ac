import numpy as np
import pytest

from lerobot_kvm.envs.env import KvmObsolescenceEnv

TASK = "pen_vs_brush"


def bent(env) -> float:
    """Permanent set (m) of the tool tip's plastic mount."""
    jnt = env.model.joint("tool_tip").id
    return abs(float(env.data.plastic[env.model.jnt_plasticadr[jnt]]))


@pytest.mark.parametrize("seed", [0, 1])
def test_pressing_draws_with_the_pen_and_bends_the_brush(run_expert, seed):
    run = run_expert(TASK, "prior", "press_stroke", seed)
    info, env = run.info, run.env
    assert info["is_success"] and not info["catastrophe"]
    assert bent(env) == 0.0
    run = run_expert(TASK, "shifted", "press_stroke", seed)
    info, env = run.info, run.env
    assert info["catastrophe"] and info["catastrophe_kind"] == "damage"
    assert not info["is_success"] and bent(env) > 0.0015  # bristles stay bent


@pytest.mark.parametrize("variant", ["prior", "shifted"])
def test_light_stroke_draws_with_either_tool(run_expert, variant):
    run = run_expert(TASK, variant, "light_stroke")
    info, env = run.info, run.env
    assert info["is_success"] and not info["catastrophe"]
    assert bent(env) == 0.0


def test_brush_pushes_back_less_at_the_same_depth(run_expert):
    """Rule 3: pressed the same 2 mm past first contact, the soft brush loads the wrist far less than the pen."""
    run = run_expert(TASK, "prior", "light_stroke")
    pen = run.contexts("stroke")
    run = run_expert(TASK, "shifted", "light_stroke")
    brush = run.contexts("stroke")
    wrist_force_z = 2  # the surface pushing up on the tool lowers this reading
    assert brush[:, wrist_force_z].mean() - pen[:, wrist_force_z].mean() > 0.4


def test_a_different_tool_in_view_and_in_words():
    a = KvmObsolescenceEnv(task=TASK, variant="prior")
    b = KvmObsolescenceEnv(task=TASK, variant="shifted")
    obs_a, _ = a.reset(seed=5)
    obs_b, _ = b.reset(seed=5)
    assert set(obs_a) == {"pixels", "agent_pos", "context"}
    assert np.abs(obs_a["pixels"]["front"].astype(float) - obs_b["pixels"]["front"].astype(float)).mean() > 0
    assert "brush" in b.task_description and "pen" in a.task_description
    with pytest.raises(ValueError, match="no skill"):
        a.scenario.expert("scribble")
