"""B9 chip bag: a firm grasp is cushioned by an unopened bag and crushes the chips in an opened one."""

import numpy as np
import pytest

from lerobot_kvm.envs.env import KvmObsolescenceEnv


def run(variant: str, skill: str, seed: int = 0) -> tuple[dict, list[float], KvmObsolescenceEnv]:
    env = KvmObsolescenceEnv(task="chip_bag", variant=variant)
    env.reset(seed=seed)
    expert = env.scenario.expert(skill)
    widths = []
    for _ in range(env._max_episode_steps):
        _, _, terminated, truncated, info = env.step(expert.act(env.physics))
        widths.append(env.sensors.finger_width(env.data))
        if terminated or truncated:
            break
    return info, widths, env


@pytest.mark.parametrize("seed", [0, 5])
def test_firm_grasp_crushes_chips_only_in_the_opened_bag(seed):
    info, _, env = run("shifted", "firm_grasp", seed)
    assert info["catastrophe"] and info["catastrophe_kind"] == "crush"
    info, _, env = run("prior", "firm_grasp", seed)
    assert info["is_success"] and not info["catastrophe"]
    assert env.scenario.max_chip_force < 1.0  # the air cushion kept the walls off the chips


def test_gentle_grasp_lifts_the_opened_bag_intact():
    info, _, env = run("shifted", "gentle_grasp", seed=2)
    assert info["is_success"] and not info["catastrophe"]
    assert env.scenario.max_chip_force < 6.0


def test_less_inflated_control_bag_still_lifts_with_the_firm_grasp():
    info, control, _ = run("control", "firm_grasp", seed=3)
    assert info["is_success"] and not info["catastrophe"]
    _, prior, _ = run("prior", "firm_grasp", seed=3)
    assert max(control) > max(prior) + 0.002  # it gives a little more under the same squeeze


def test_opened_bag_gives_way_under_the_fingers():
    """Rule 3: the shift is sensed as extra finger travel while squeezing."""
    _, opened, _ = run("shifted", "gentle_grasp", seed=1)
    _, sealed, _ = run("prior", "gentle_grasp", seed=1)
    assert max(opened) > max(sealed) + 0.015


def test_same_look_and_instruction():
    env = KvmObsolescenceEnv(task="chip_bag")
    a, _ = env.reset(seed=4, options={"variant": "prior"})
    text = env.task_description
    b, _ = env.reset(seed=4, options={"variant": "shifted"})
    assert env.task_description == text
    assert np.abs(a["pixels"]["front"].astype(float) - b["pixels"]["front"].astype(float)).mean() <= 2.0
