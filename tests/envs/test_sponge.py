"""A2 sponge: a light, quick pinch lifts a dry sponge and loses a soaked one mid-lift."""

import pytest

from lerobot_kvm.envs.env import KvmObsolescenceEnv
from lerobot_kvm.envs.scenarios.sponge import AIRBORNE, HALF, HAND_TOP
from lerobot_kvm.envs.sensing import FRAME_NAMES
from lerobot_kvm.evaluation.suite_check import run_episode


@pytest.mark.parametrize("seed", [0, 1])
def test_light_grasp_drops_the_soaked_sponge_and_lifts_the_dry_one(seed):
    env = KvmObsolescenceEnv(task="sponge")
    soaked = run_episode(env, "shifted", "light_grasp", seed)
    assert soaked.catastrophe_kind == "drop" and not soaked.success
    # It slid out of the fingers in the air: no touch left, the sponge still above the table.
    assert env.sensors.touch(env.data).max() == 0.0
    assert env.data.body("sponge").xpos[2] > HALF[2] + AIRBORNE
    dry = run_episode(env, "prior", "light_grasp", seed)
    assert dry.success and not dry.catastrophe_kind


def test_light_grasp_still_lifts_the_damp_control_sponge():
    env = KvmObsolescenceEnv(task="sponge")
    damp = run_episode(env, "control", "light_grasp", seed=2)
    assert damp.success and not damp.catastrophe_kind


def test_firm_grasp_carries_the_soaked_sponge():
    env = KvmObsolescenceEnv(task="sponge")
    soaked = run_episode(env, "shifted", "firm_grasp", seed=3)
    assert soaked.success and not soaked.catastrophe_kind
    assert env.sensors.arm_position(env.data)[2] <= HAND_TOP + 0.005  # the lift stops at its top


def test_soaked_sponge_weighs_on_the_wrist():
    """Rule 3: held in the same firm grasp, the soaked sponge pulls the wrist down far harder."""
    env = KvmObsolescenceEnv(task="sponge")
    force_z = FRAME_NAMES.index("wrist_force_z")
    held = {}
    for variant in ("prior", "shifted"):
        assert run_episode(env, variant, "firm_grasp", seed=0).success
        held[variant] = env.sensors.context(env.data, env.arm_target, env.last_action)[force_z]
    assert held["shifted"] - held["prior"] > 2.0  # about 0.3 kg more under gravity
