"""Contract every registered scenario must meet; cheap checks only (expert episodes live in per-scenario tests)."""

import re

import numpy as np
import pytest

from lerobot_kvm.envs.catalogue import CATEGORIES, VARIANTS
from lerobot_kvm.envs.env import KvmObsolescenceEnv
from lerobot_kvm.envs.physics import holds_tool, robot_geom_mask, robot_in_contact
from lerobot_kvm.envs.scenario import SCENARIOS, Expert

IDS = sorted(SCENARIOS)


@pytest.fixture(scope="module")
def envs():
    """One env per scenario shared by this module's tests: building and first rendering dominate the cost."""
    cache: dict[str, KvmObsolescenceEnv] = {}

    def get(sid: str) -> KvmObsolescenceEnv:
        if sid not in cache:
            cache[sid] = KvmObsolescenceEnv(task=sid)
        return cache[sid]

    yield get
    for env in cache.values():
        env.close()


def hold_action(obs: dict) -> np.ndarray:
    """Keep the arm where it is with the gripper open: moves nothing, so any drift is the env's own."""
    return np.array([*obs["agent_pos"][:4], -1.0], dtype=np.float32)


@pytest.mark.parametrize("sid", IDS)
def test_observation_has_only_the_public_keys_and_matches_the_space(sid, envs):
    env = envs(sid)
    for variant in ("prior", "shifted"):
        obs, info = env.reset(seed=0, options={"variant": variant})
        assert set(obs) == {"pixels", "agent_pos", "context"}
        assert set(obs["pixels"]) == {"front"}
        assert env.observation_space.contains(obs), f"{sid}/{variant}: observation outside observation_space"
        obs, *_ = env.step(hold_action(obs))
        assert env.observation_space.contains(obs)
        assert set(info) >= {"is_success", "catastrophe", "catastrophe_kind"}
        assert env.task_description == SCENARIOS[sid].info.instructions[variant]


@pytest.mark.parametrize("sid", IDS)
def test_scenario_info_is_complete(sid):
    info = SCENARIOS[sid].info
    assert info.id == sid and info.category in CATEGORIES
    assert {"prior", "shifted"} <= set(info.variants) <= set(VARIANTS)
    assert all(isinstance(info.instructions.get(v), str) and info.instructions[v].strip() for v in info.variants)
    same = info.instructions["prior"] == info.instructions["shifted"]
    assert same if info.category in ("A", "B") else not same, "A/B hide the shift in the instruction; C renames"
    assert info.prior_skill != info.safe_skill
    assert {info.prior_skill, info.safe_skill} <= set(info.skill_instructions)
    assert all(text.strip() for text in (info.title, info.harm, info.what_changes, info.success))
    assert info.max_steps > 0
    scenario = SCENARIOS[sid]()
    assert set(scenario.skills) == {info.prior_skill, info.safe_skill}
    assert all(isinstance(scenario.expert(skill), Expert) for skill in (info.prior_skill, info.safe_skill))
    with pytest.raises(ValueError, match=re.escape(f"{sid} has no skill 'juggle'; it has {sorted(scenario.skills)}")):
        scenario.expert("juggle")


@pytest.mark.parametrize("sid", IDS)
def test_reset_is_deterministic_for_a_seed(sid, envs):
    """Same seed, same first observation: after steps in the same env, and in a second env with its own history."""
    env, other = envs(sid), KvmObsolescenceEnv(task=sid)
    for variant in ("prior", "shifted"):
        first, _ = env.reset(seed=5, options={"variant": variant})
        for _ in range(3):
            env.step(hold_action(first))
        again, _ = env.reset(seed=5, options={"variant": variant})
        elsewhere, _ = other.reset(seed=5, options={"variant": variant})
        for obs in (again, elsewhere):
            np.testing.assert_array_equal(obs["pixels"]["front"], first["pixels"]["front"])
            np.testing.assert_array_equal(obs["agent_pos"], first["agent_pos"])
            np.testing.assert_array_equal(obs["context"], first["context"])
    other.close()


def run_until_contact(env: KvmObsolescenceEnv, variant: str, seed: int, actions: list[np.ndarray] | None = None):
    """Contexts until the robot first touches anything but itself (a held tool counts from the start), with the
    prior skill's expert or replaying `actions`; returns (contexts, actions, first contact index)."""
    robot = robot_geom_mask(env.model)
    obs, _ = env.reset(seed=seed, options={"variant": variant})
    expert = env.scenario.expert(env.scenario.info.prior_skill)
    contexts, taken = [obs["context"]], []
    if holds_tool(env.model):
        return contexts, taken, 0
    for t in range(env._max_episode_steps):
        action = expert.act(env.physics) if actions is None else actions[t]
        taken.append(action)
        obs, _, terminated, truncated, _ = env.step(action)
        contexts.append(obs["context"])
        if robot_in_contact(env.data, robot):
            return contexts, taken, len(contexts) - 1
        if terminated or truncated or (actions is not None and t + 1 == len(actions)):
            break
    return contexts, taken, len(contexts)


@pytest.mark.parametrize("sid", IDS)
def test_context_is_identical_between_variants_until_the_robot_touches_something(sid, envs):
    """Rule 3, sensed not told: under the same actions no observation channel carries the variant before the
    robot touches the object (the scripted expert reads object poses, so the shifted run replays its actions)."""
    env = envs(sid)
    prior, actions, prior_contact = run_until_contact(env, "prior", seed=7)
    shifted, _, shifted_contact = run_until_contact(env, "shifted", seed=7, actions=actions)
    until = min(prior_contact, shifted_contact)
    if until == 0:  # a held tool (or what it holds) touches the robot from the start: nothing is unsensed
        assert holds_tool(env.model) or prior_contact == 0
        return
    np.testing.assert_allclose(np.stack(prior[:until]), np.stack(shifted[:until]), rtol=0, atol=1e-6)


def test_instruction_option_asks_for_the_variant_or_a_named_skill():
    from lerobot_kvm.envs.configuration_kvm_obsolescence import KvmObsolescenceEnvConfig

    env = KvmObsolescenceEnv(task="egg_vs_stone", instruction="safe")
    assert env.task_description == "gently pick up the stone"
    env.reset(seed=0, options={"variant": "shifted"})
    assert env.task_description == "gently pick up the stone"  # the skill's instruction names the prior object
    env.close()
    assert KvmObsolescenceEnvConfig(instruction="prior").gym_kwargs["instruction"] == "prior"
    with pytest.raises(ValueError, match="loudly"):
        KvmObsolescenceEnvConfig(instruction="loudly")
