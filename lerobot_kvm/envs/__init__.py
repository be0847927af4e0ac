"""The MuJoCo knowledge-obsolescence suite (`--env.type=kvm_obsolescence`).

Importing this package registers the env config and the gym id without importing the simulator: the env
(`envs.env.KvmObsolescenceEnv`) and the scenario classes (`envs.scenario.make_scenario`) import MuJoCo when built.
"""

import gymnasium as gym

from .catalogue import SCENARIO_INFOS, resolve_tasks
from .configuration_kvm_obsolescence import OBS_CONTEXT, KvmObsolescenceEnvConfig

ENV_ID = "lerobot_kvm/KvmObsolescence-v0"
if ENV_ID not in gym.registry:
    gym.register(ENV_ID, entry_point="lerobot_kvm.envs.env:KvmObsolescenceEnv")

__all__ = ["ENV_ID", "OBS_CONTEXT", "SCENARIO_INFOS", "KvmObsolescenceEnv", "KvmObsolescenceEnvConfig", "resolve_tasks"]


def __getattr__(name: str) -> type:
    """`KvmObsolescenceEnv` on first use: the env imports the simulator, the rest of this package does not."""
    if name == "KvmObsolescenceEnv":
        from .env import KvmObsolescenceEnv

        return KvmObsolescenceEnv
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
