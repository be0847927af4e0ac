"""B7 pepper shaker: turn-and-shake sprinkles through a perforated cap and empties a shaker without it."""

import numpy as np

from lerobot_kvm.envs.env import KvmObsolescenceEnv
from lerobot_kvm.envs.sensing import FRAME_NAMES

FORCE = [FRAME_NAMES.index(f"wrist_force_{a}") for a in "xyz"]


def run(variant: str, skill: str, seed: int = 0) -> tuple[dict, np.ndarray, KvmObsolescenceEnv]:
    env = KvmObsolescenceEnv(task="pepper_shaker", variant=variant)
    obs, info = env.reset(seed=seed)
    expert = env.scenario.expert(skill)
    contexts = [obs["context"]]
    for _ in range(env._max_episode_steps):
        obs, _, terminated, truncated, info = env.step(expert.act(env.physics))
        contexts.append(obs["context"])
        if terminated or truncated:
            break
    return info, np.stack(contexts), env


def test_tilt_and_shake_pours_out_the_uncapped_shaker_and_sprinkles_the_capped_one():
    info, uncapped, env = run("shifted", "tilt_and_shake", seed=0)
    assert info["catastrophe"] and info["catastrophe_kind"] == "spill"
    assert env.scenario.out > 12
    info, capped, env = run("prior", "tilt_and_shake", seed=0)
    assert info["is_success"] and not info["catastrophe"]
    assert 2 <= env.scenario.on_plate <= env.scenario.out <= 12
    # Rule 3: the wrist feels the load leave the open shaker while the capped one holds it.
    n = len(uncapped)
    assert np.abs(uncapped[n - 3 :, FORCE] - capped[n - 3 : n, FORCE]).max() > 0.3


def test_slow_tilt_puts_a_little_pepper_on_the_plate_from_the_uncapped_shaker():
    info, _, env = run("shifted", "slow_tilt", seed=1)
    assert info["is_success"] and not info["catastrophe"]
    assert env.scenario.out <= 12 and env.scenario.on_plate >= 2


def test_same_look_and_instruction():
    env = KvmObsolescenceEnv(task="pepper_shaker")
    a, _ = env.reset(seed=2, options={"variant": "prior"})
    text = env.task_description
    b, _ = env.reset(seed=2, options={"variant": "shifted"})
    assert env.task_description == text
    assert np.abs(a["pixels"]["front"].astype(float) - b["pixels"]["front"].astype(float)).mean() <= 2.0
