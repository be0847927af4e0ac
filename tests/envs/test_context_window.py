"""The sensed context with history: each step's frame joined with earlier ones, in the env and its config."""

import numpy as np
import pytest

from lerobot_kvm.envs import KvmObsolescenceEnvConfig
from lerobot_kvm.envs.env import KvmObsolescenceEnv
from lerobot_kvm.envs.sensing import FRAME_NAMES, ContextWindow, context_names


def test_the_window_joins_each_frame_with_the_frames_its_lags_before() -> None:
    window = ContextWindow((1, 2, 4))
    contexts = [window.push(np.array([float(t)])) for t in range(7)]
    # the episode's first frame stands in for frames older than the episode
    assert [c.tolist() for c in contexts] == [
        [0, 0, 0, 0],
        [1, 0, 0, 0],
        [2, 1, 0, 0],
        [3, 2, 1, 0],
        [4, 3, 2, 0],
        [5, 4, 3, 1],
        [6, 5, 4, 2],
    ]
    window.reset()
    assert window.push(np.array([9.0])).tolist() == [9, 9, 9, 9]
    assert ContextWindow().push(np.array([1.0, 2.0])).tolist() == [1, 2]  # no lags: the frame alone
    assert window.names == context_names((1, 2, 4)) and len(window.names) == 4 * len(FRAME_NAMES)
    with pytest.raises(ValueError, match="positive"):
        ContextWindow((0, 2))


def test_the_environment_senses_its_context_window() -> None:
    env = KvmObsolescenceEnv("drawer", context_lags=(1, 2))
    n = len(FRAME_NAMES)
    assert env.observation_space["context"].shape == (3 * n,)
    obs, _ = env.reset(seed=0)
    frames = [obs["context"][:n]]
    assert np.array_equal(obs["context"], np.tile(frames[0], 3))
    expert = env.scenario.expert(env.scenario.info.prior_skill)
    for _ in range(3):
        obs, *_ = env.step(expert.act(env.physics))
        frames.append(obs["context"][:n])
    assert np.array_equal(obs["context"], np.concatenate([frames[3], frames[2], frames[1]]))
    obs, _ = env.reset(seed=0)  # a new episode starts a new window
    assert np.array_equal(obs["context"], np.tile(frames[0], 3))
    env.close()
    config = KvmObsolescenceEnvConfig(task="drawer", context_lags=[1, 2])
    assert config.features["context"].shape == (3 * n,) and config.gym_kwargs["context_lags"] == (1, 2)
