import numpy as np
import pytest

from lerobot_kvm.envs.env import KvmObsolescenceEnv

TASK = "pen_vs_brush"


def run_expert(variant: str, skill: str, seed: int = 0):
    """Run a scripted expert; returns the last info, the env (open) and the contexts while drawing."""
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


def bent(env) -> float:
    """Permanent set (m) of the tool tip's plastic mount."""
    jnt = env.model.joint("tool_tip").id
    return abs(float(env.data.plastic[env.model.jnt_plasticadr[jnt]]))


@pytest.mark.parametrize("seed", [0, 1])
def test_pressing_draws_with_the_pen_and_bends_the_brush(seed):
    info, env, _ = run_expert("prior", "press_stroke", seed)
    assert info["is_success"] and not info["catastrophe"]
    assert bent(env) == 0.0
    info, env, _ = run_expert("shifted", "press_stroke", seed)
    assert info["catastrophe"] and info["catastrophe_kind"] == "damage"
    assert not info["is_success"] and bent(env) > 0.0015  # bristles stay bent


@pytest.mark.parametrize("variant", ["prior", "shifted"])
def test_light_stroke_draws_with_either_tool(variant):
    info, env, _ = run_expert(variant, "light_stroke")
    assert info["is_success"] and not info["catastrophe"]
    assert bent(env) == 0.0


def test_brush_pushes_back_less_at_the_same_depth():
    """Rule 3: pressed the same 2 mm past first contact, the soft brush loads the wrist far less than the pen."""
    _, _, pen = run_expert("prior", "light_stroke")
    _, _, brush = run_expert("shifted", "light_stroke")
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
