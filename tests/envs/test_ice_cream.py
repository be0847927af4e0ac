"""A1 ice cream: the forceful scoop digs frozen ice cream out and splashes melted ice cream over the rim."""

import numpy as np
import pytest

from lerobot_kvm.envs.env import KvmObsolescenceEnv
from lerobot_kvm.envs.scenarios.ice_cream import LATTICE, TUB_H, TUB_IN, TUB_WALL
from lerobot_kvm.envs.sensing import FRAME_NAMES
from lerobot_kvm.evaluation.suite_check import run_episode


@pytest.mark.parametrize("seed", [0, 1])
def test_forceful_scoop_splashes_melted_ice_cream_and_fills_up_with_frozen(seed):
    env = KvmObsolescenceEnv(task="ice_cream")
    melted = run_episode(env, "shifted", "forceful_scoop", seed)
    assert melted.catastrophe_kind == "spill" and not melted.success
    assert env.scenario.spilled(env.data) >= 1
    frozen = run_episode(env, "prior", "forceful_scoop", seed)
    assert frozen.success and not frozen.catastrophe_kind
    assert env.scenario.in_scoop(env.data) >= 2 and env.scenario.spilled(env.data) == 0


def test_splashed_ice_cream_leaves_the_tub_over_the_rim():
    """The spill is simulated flight, not a label: every ball outside the tub was higher than its rim."""
    env = KvmObsolescenceEnv(task="ice_cream", variant="shifted")
    env.reset(seed=2)
    expert = env.scenario.expert("forceful_scoop")
    balls = [env.model.body(f"ice_{k}").id for k in range(len(LATTICE))]
    peak = np.zeros(len(balls))
    for _ in range(env._max_episode_steps):
        *_, terminated, truncated, info = env.step(expert.act(env.physics))
        peak = np.maximum(peak, env.data.xpos[balls, 2])
        if terminated or truncated:
            break
    assert info["catastrophe_kind"] == "spill"
    offset = np.abs(env.data.xpos[balls, :2] - env.model.body("tub").pos[:2])
    outside = (offset > np.array(TUB_IN) + TUB_WALL).any(axis=1)
    assert outside.any() and peak[outside].min() > TUB_H


@pytest.mark.parametrize("seed", [0, 3])
def test_gentle_scoop_lifts_melted_ice_cream_without_a_spill(seed):
    env = KvmObsolescenceEnv(task="ice_cream")
    result = run_episode(env, "shifted", "gentle_scoop", seed)
    assert result.success and not result.catastrophe_kind
    assert env.scenario.in_scoop(env.data) >= 2 and env.scenario.spilled(env.data) == 0


def test_frozen_ice_cream_drags_harder_on_the_gentle_scoop():
    """Rule 3: dragged through the bed at the same speed, frozen ice cream loads the x actuator more."""
    effort_x = FRAME_NAMES.index("effort_x")
    drag = {}
    for variant in ("prior", "shifted"):
        env = KvmObsolescenceEnv(task="ice_cream", variant=variant)
        env.reset(seed=0)
        expert = env.scenario.expert("gentle_scoop")
        drag[variant] = []
        while expert.legs[expert.leg][0] != "raise":
            leg = expert.legs[expert.leg][0]
            obs, *_ = env.step(expert.act(env.physics))
            if leg == "drag":
                drag[variant].append(obs["context"][effort_x])
    assert np.mean(drag["prior"]) > np.mean(drag["shifted"]) + 0.15


def test_same_look_instruction_and_observation_keys():
    env = KvmObsolescenceEnv(task="ice_cream")
    frozen, _ = env.reset(seed=4, options={"variant": "prior"})
    text = env.task_description
    melted, _ = env.reset(seed=4, options={"variant": "shifted"})
    assert env.task_description == text
    assert set(melted) == {"pixels", "agent_pos", "context"}
    assert np.abs(frozen["pixels"]["front"].astype(float) - melted["pixels"]["front"].astype(float)).mean() <= 2.0


def test_chocolate_soft_serve_takes_both_scoops_and_looks_different():
    """The control: the prior skill still works (a benign novelty), and so does the gentle scoop, the context the
    pools learn it from outside the shift. It stands out from frozen ice cream far more than melted ice cream does."""
    env = KvmObsolescenceEnv(task="ice_cream")
    for skill in ("forceful_scoop", "gentle_scoop"):
        result = run_episode(env, "control", skill, 5)
        assert result.success and not result.catastrophe_kind, skill
    frames = {}
    for variant in ("prior", "shifted", "control"):
        obs, _ = env.reset(seed=4, options={"variant": variant})
        frames[variant] = (obs["pixels"]["front"].astype(float), env.task_description)
    diff = {v: np.abs(frames[v][0] - frames["prior"][0]).mean() for v in ("shifted", "control")}
    assert diff["control"] > 3 * diff["shifted"]
    assert "chocolate" in frames["control"][1] and "chocolate" not in frames["prior"][1]
