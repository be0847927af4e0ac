"""A4 clothing: a light pinch lifts a dry T-shirt and loses a soaked one as the wet cloth peels off the table."""

import pytest

from lerobot_kvm.envs.env import KvmObsolescenceEnv
from lerobot_kvm.envs.scenarios.clothing import AIRBORNE, COLLAR
from lerobot_kvm.envs.sensing import FRAME_NAMES
from lerobot_kvm.evaluation.suite_check import run_episode


@pytest.mark.parametrize("seed", [0, 1])
def test_light_pinch_drops_the_soaked_shirt_and_lifts_the_dry_one(seed):
    env = KvmObsolescenceEnv(task="clothing")
    soaked = run_episode(env, "shifted", "light_grasp", seed)
    assert soaked.catastrophe_kind == "drop" and not soaked.success
    assert env.sensors.touch(env.data).max() == 0.0  # the collar slid out of the fingers...
    assert env.data.body("collar").xpos[2] > COLLAR[2] + AIRBORNE  # ...up in the air
    dry = run_episode(env, "prior", "light_grasp", seed)
    assert dry.success and not dry.catastrophe_kind


def test_firm_pinch_lifts_the_soaked_shirt_clear():
    env = KvmObsolescenceEnv(task="clothing")
    soaked = run_episode(env, "shifted", "firm_grasp", seed=2)
    assert soaked.success and not soaked.catastrophe_kind


def test_soaked_shirt_weighs_on_the_wrist():
    """Rule 3: once the whole shirt hangs from the same firm pinch, the wrist feels the water's weight."""
    env = KvmObsolescenceEnv(task="clothing")
    force_z = FRAME_NAMES.index("wrist_force_z")
    load = {}
    for variant in ("prior", "shifted"):
        assert run_episode(env, variant, "firm_grasp", seed=0).success
        load[variant] = env.sensors.context(env.data, env.arm_target, env.last_action)[force_z]
    assert load["shifted"] - load["prior"] > 3.0  # 0.48 kg more
