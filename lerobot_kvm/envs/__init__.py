"""The MuJoCo knowledge-obsolescence suite (`--env.type=kvm_obsolescence`)."""

import gymnasium as gym

from .configuration_kvm_obsolescence import OBS_CONTEXT, KvmObsolescenceEnvConfig
from .env import KvmObsolescenceEnv
from .scenario import SCENARIOS, make_scenario, resolve_tasks

ENV_ID = "lerobot_kvm/KvmObsolescence-v0"
if ENV_ID not in gym.registry:
    gym.register(ENV_ID, entry_point="lerobot_kvm.envs.env:KvmObsolescenceEnv")

__all__ = [
    "ENV_ID",
    "OBS_CONTEXT",
    "SCENARIOS",
    "KvmObsolescenceEnv",
    "KvmObsolescenceEnvConfig",
    "make_scenario",
    "resolve_tasks",
]
