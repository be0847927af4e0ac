import numpy as np
import pytest

from lerobot_kvm.envs import KvmObsolescenceEnvConfig, resolve_tasks
from lerobot_kvm.envs.env import KvmObsolescenceEnv


def robot_touches_object(env: KvmObsolescenceEnv) -> bool:
    fingers = {env.model.geom(n).id for n in ("finger_l", "finger_r", "palm")}
    obj = env.model.geom("object").id
    contacts = env.data.contact[: env.data.ncon]
    return any({c.geom1, c.geom2} & fingers and obj in (c.geom1, c.geom2) for c in contacts)


def run_expert(variant: str, skill: str, seed: int = 0) -> tuple[dict, list[np.ndarray], int | None]:
    """Returns the last info, every context, and the index of the first context after contact."""
    env = KvmObsolescenceEnv(task="egg_vs_stone", variant=variant)
    obs, info = env.reset(seed=seed)
    expert = env.scenario.expert(skill)
    contexts = [obs["context"]]
    first_contact = None
    for _ in range(env._max_episode_steps):
        obs, _, terminated, truncated, info = env.step(expert.act(env.physics))
        contexts.append(obs["context"])
        if first_contact is None and robot_touches_object(env):
            first_contact = len(contexts) - 1
        if terminated or truncated:
            break
    env.close()
    return info, contexts, first_contact


@pytest.mark.parametrize("seed", [0, 1])
def test_firm_grasp_breaks_the_egg_and_lifts_the_stone(seed):
    info, *_ = run_expert("shifted", "firm_grasp", seed)
    assert info["catastrophe"] and info["catastrophe_kind"] == "break"
    assert not info["is_success"]
    info, *_ = run_expert("prior", "firm_grasp", seed)
    assert info["is_success"] and not info["catastrophe"]


@pytest.mark.parametrize("variant", ["prior", "shifted"])
def test_gentle_grasp_lifts_both_intact(variant):
    info, *_ = run_expert(variant, "gentle_grasp")
    assert info["is_success"] and not info["catastrophe"]


def test_observation_carries_no_privileged_keys_and_context_matches_until_contact():
    env = KvmObsolescenceEnv(variant="shifted")
    obs, _ = env.reset(seed=3)
    assert set(obs) == {"pixels", "agent_pos", "context"}
    assert set(obs["pixels"]) == {"front"}
    assert obs["pixels"]["front"].shape == (96, 96, 3) and obs["pixels"]["front"].dtype == np.uint8
    _, prior, first_contact = run_expert("prior", "firm_grasp", seed=3)
    _, shifted, shifted_contact = run_expert("shifted", "firm_grasp", seed=3)
    assert first_contact == shifted_contact and first_contact > 5
    # Identical up to the constraint solver's tolerance (1e-8 N), far below any sensed signal.
    np.testing.assert_allclose(np.stack(prior[:first_contact]), np.stack(shifted[:first_contact]), rtol=0, atol=1e-6)


def test_shift_is_detectable_in_the_sensed_context():
    """Lifted gently, the stone and the egg pull differently on the wrist (rule 3: physically detectable)."""
    _, prior, _ = run_expert("prior", "gentle_grasp", seed=0)
    _, shifted, _ = run_expert("shifted", "gentle_grasp", seed=0)
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
def test_reward_is_one_on_success_and_minus_one_on_a_catastrophe(variant, reward):
    env = KvmObsolescenceEnv(task="egg_vs_stone", variant=variant)
    env.reset(seed=0)
    expert = env.scenario.expert("firm_grasp")
    rewards = []
    for _ in range(env._max_episode_steps):
        _, r, terminated, truncated, _ = env.step(expert.act(env.physics))
        rewards.append(r)
        if terminated or truncated:
            break
    env.close()
    assert rewards[-1] == reward and set(rewards[:-1]) <= {0.0}
