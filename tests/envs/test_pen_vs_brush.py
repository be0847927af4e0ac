import numpy as np
import pytest

from lerobot_kvm.envs import KvmObsolescenceEnv

TASK = "pen_vs_brush"


def run_expert(variant: str, skill: str, seed: int = 0):
    """Run a scripted expert; returns the last info, the env (open) and the hand heights while drawing."""
    env = KvmObsolescenceEnv(task=TASK, variant=variant)
    env.reset(seed=seed)
    expert = env.scenario.expert(skill)
    stroke_z = []
    for _ in range(env._max_episode_steps):
        obs, _, terminated, truncated, info = env.step(expert.act(env))
        if expert.phase == "stroke":
            stroke_z.append(obs["agent_pos"][2])
        if terminated or truncated:
            break
    return info, env, np.array(stroke_z)


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


def test_brush_gives_way_under_the_same_light_force():
    """Rule 3: regulating the same light wrist force, the hand sits lower with the soft brush tip."""
    _, _, pen = run_expert("prior", "light_stroke")
    _, _, brush = run_expert("shifted", "light_stroke")
    assert pen.mean() - brush.mean() > 0.0005


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
