import numpy as np
import pytest

from lerobot_kvm.envs import KvmObsolescenceEnvConfig, resolve_tasks
from lerobot_kvm.envs.env import KvmObsolescenceEnv
from lerobot_kvm.envs.scenarios.egg_vs_stone import POSITION_SPREAD, RADII, EggVsStone

TASK = "egg_vs_stone"


def robot_touches_object(env: KvmObsolescenceEnv) -> bool:
    fingers = {env.model.geom(n).id for n in ("finger_l", "finger_r", "palm")}
    obj = env.model.geom("object").id
    contacts = env.data.contact[: env.data.ncon]
    return any({c.geom1, c.geom2} & fingers and obj in (c.geom1, c.geom2) for c in contacts)


@pytest.mark.parametrize("seed", [0, 1])
def test_firm_grasp_breaks_the_egg_and_lifts_the_stone(run_expert, seed):
    info = run_expert(TASK, "shifted", "firm_grasp", seed).info
    assert info["catastrophe"] and info["catastrophe_kind"] == "break"
    assert not info["is_success"]
    info = run_expert(TASK, "prior", "firm_grasp", seed).info
    assert info["is_success"] and not info["catastrophe"]


@pytest.mark.parametrize("corner", [(1, 1), (-1, 1), (1, -1), (-1, -1)])
def test_a_firm_grasp_aimed_at_the_centre_lifts_the_stone_anywhere_in_the_spread(corner):
    """A learned grasp that does not read the stone's position from the image closes where the demonstrations did
    on average; placed there, the firm squeeze must still hold the stone wherever the spread puts it (15 mm
    squeezed it out beyond about 13 mm along the fingers' faces: docs/measurements.md, "The egg's spread")."""
    env = KvmObsolescenceEnv(variant="prior")
    env.reset(seed=0)
    adr = env.model.jnt_qposadr[env.model.body("object").jntadr[0]]
    env.data.qpos[adr : adr + 2] = np.array(corner) * POSITION_SPREAD
    # the scenario's own firm grasp, aimed at the origin (the world body) at the stone's height
    expert = EggVsStone.skills["firm_grasp"](body="world", grasp_height=RADII[2])
    for _ in range(env._max_episode_steps):
        _, _, terminated, truncated, info = env.step(expert.act(env.physics))
        if terminated or truncated:
            break
    env.close()
    assert info["is_success"]


@pytest.mark.parametrize("variant", ["prior", "shifted"])
def test_gentle_grasp_lifts_both_intact(run_expert, variant):
    info = run_expert(TASK, variant, "gentle_grasp").info
    assert info["is_success"] and not info["catastrophe"]


def test_observation_carries_no_privileged_keys_and_context_matches_until_contact(run_expert):
    env = KvmObsolescenceEnv(variant="shifted")
    obs, _ = env.reset(seed=3)
    assert set(obs) == {"pixels", "agent_pos", "context"}
    assert set(obs["pixels"]) == {"front"}
    assert obs["pixels"]["front"].shape == (96, 96, 3) and obs["pixels"]["front"].dtype == np.uint8
    prior = run_expert(TASK, "prior", "firm_grasp", seed=3, probe=robot_touches_object)
    shifted = run_expert(TASK, "shifted", "firm_grasp", seed=3, probe=robot_touches_object)
    first_contact = 1 + prior.probes.index(True)  # index of the first context sensed in contact (reset's is 0)
    assert first_contact == 1 + shifted.probes.index(True) and first_contact > 5
    # Identical up to the constraint solver's tolerance (1e-8 N), far below any sensed signal.
    np.testing.assert_allclose(prior.contexts()[:first_contact], shifted.contexts()[:first_contact], rtol=0, atol=1e-6)


def test_shift_is_detectable_in_the_sensed_context(run_expert):
    """Lifted gently, the stone and the egg pull differently on the wrist (rule 3: physically detectable)."""
    prior = run_expert(TASK, "prior", "gentle_grasp", seed=0).contexts()
    shifted = run_expert(TASK, "shifted", "gentle_grasp", seed=0).contexts()
    force_z = 2
    assert abs(prior[-1][force_z] - shifted[-1][force_z]) > 1.0


def test_grip_command_is_rate_limited():
    env = KvmObsolescenceEnv()
    obs, _ = env.reset(seed=0)
    action = np.array([*obs["agent_pos"][:4], 1.0], dtype=np.float32)
    obs, *_ = env.step(action)
    assert obs["agent_pos"][5] == pytest.approx(-1.0 + 0.12)


def test_bad_inputs_raise_clear_errors():
    with pytest.raises(ValueError, match="unknown scenario"):
        KvmObsolescenceEnv(task="no_such_thing")
    with pytest.raises(ValueError, match="variant"):
        KvmObsolescenceEnv(variant="sideways")
    env = KvmObsolescenceEnv()
    env.reset(seed=0)
    with pytest.raises(ValueError, match="shape"):
        env.step(np.zeros(3))
    with pytest.raises(ValueError, match="non-finite"):
        env.step(np.array([0, 0, 0.2, 0, np.nan]))
    with pytest.raises(ValueError, match="unknown task"):
        KvmObsolescenceEnvConfig(task="nope")
    with pytest.raises(ValueError, match="variant"):
        KvmObsolescenceEnvConfig(variant="nope")


def test_task_resolution_and_vector_envs():
    assert resolve_tasks("egg_vs_stone") == ["egg_vs_stone"]
    assert "egg_vs_stone" in resolve_tasks("C") and "egg_vs_stone" in resolve_tasks("all")
    envs = KvmObsolescenceEnvConfig(task="egg_vs_stone", variant="shifted").create_envs(2)
    vec = envs["egg_vs_stone"][0]
    obs, _ = vec.reset(seed=[0, 1])
    assert obs["context"].shape == (2, 24)
    assert list(vec.call("task_description")) == ["pick up the egg"] * 2
    vec.close()


@pytest.mark.parametrize(("variant", "reward"), [("prior", 1.0), ("shifted", -1.0)])
def test_reward_is_one_on_success_and_minus_one_on_a_catastrophe(run_expert, variant, reward):
    rewards = run_expert(TASK, variant, "firm_grasp").rewards
    assert rewards[-1] == reward and set(rewards[:-1]) <= {0.0}
