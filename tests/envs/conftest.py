"""The one way the suite's tests run a scripted expert through an episode."""

from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pytest

from lerobot_kvm.envs.env import KvmObsolescenceEnv


@dataclass
class ExpertRun:
    """One expert episode: the last info, the env (left open for inspection until the test ends), every observation
    (the reset's first), each step's reward, the expert's phase after each step's action and what `probe(env)` read
    after each step."""

    info: dict
    env: KvmObsolescenceEnv
    observations: list[dict] = field(default_factory=list)
    rewards: list[float] = field(default_factory=list)
    phases: list[str | None] = field(default_factory=list)
    probes: list[Any] = field(default_factory=list)

    def contexts(self, phase: str | None = None) -> np.ndarray:
        """Every context (the reset's first), or those of the steps the expert spent in `phase`."""
        if phase is None:
            return np.stack([obs["context"] for obs in self.observations])
        steps = zip(self.observations[1:], self.phases, strict=True)
        return np.array([obs["context"] for obs, p in steps if p == phase])


ExpertRunner = Callable[..., ExpertRun]


@pytest.fixture
def run_expert() -> Iterator[ExpertRunner]:
    """`run_expert(task, variant, skill, seed=0, probe=None)`: run `skill`'s expert until the episode ends."""
    envs: list[KvmObsolescenceEnv] = []

    def run(
        task: str, variant: str, skill: str, seed: int = 0, probe: Callable[[KvmObsolescenceEnv], Any] | None = None
    ) -> ExpertRun:
        env = KvmObsolescenceEnv(task=task, variant=variant)
        envs.append(env)
        obs, info = env.reset(seed=seed)
        expert = env.scenario.expert(skill)
        record = ExpertRun(info, env, [obs])
        for _ in range(env._max_episode_steps):
            obs, reward, terminated, truncated, record.info = env.step(expert.act(env.physics))
            record.observations.append(obs)
            record.rewards.append(reward)
            record.phases.append(getattr(expert, "phase", None))
            if probe is not None:
                record.probes.append(probe(env))
            if terminated or truncated:
                break
        return record

    yield run
    for env in envs:
        env.close()
