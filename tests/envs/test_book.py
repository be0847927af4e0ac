import numpy as np
import pytest

from lerobot_kvm.envs.env import KvmObsolescenceEnv

TASK = "book"


def cover_dent(env) -> float:
    """Permanent set (m) of the cover panel's plastic mount."""
    jnt = env.model.joint("book_back").id
    return abs(float(env.data.plastic[env.model.jnt_plasticadr[jnt]]))


@pytest.mark.parametrize("seed", [0, 1])
def test_quick_push_slides_the_hardcover_and_dents_the_paperback(run_expert, seed):
    run = run_expert(TASK, "prior", "fast_push", seed)
    info, env = run.info, run.env
    assert info["is_success"] and not info["catastrophe"]
    assert cover_dent(env) == 0.0
    run = run_expert(TASK, "shifted", "fast_push", seed)
    info, env = run.info, run.env
    assert info["catastrophe"] and info["catastrophe_kind"] == "damage"
    assert not info["is_success"] and cover_dent(env) > 0.0005  # a real permanent deformation


def test_slow_push_slides_the_paperback_undamaged(run_expert):
    run = run_expert(TASK, "shifted", "slow_push")
    info, env = run.info, run.env
    assert info["is_success"] and not info["catastrophe"]
    assert cover_dent(env) == 0.0


def test_control_heavier_hardcover_still_takes_the_quick_push(run_expert):
    info = run_expert(TASK, "control", "fast_push").info
    assert info["is_success"] and not info["catastrophe"]


def test_hardcover_and_paperback_push_back_differently(run_expert):
    """Rule 3: sliding the heavier hardcover loads the wrist along the push more than the paperback."""
    run = run_expert(TASK, "prior", "slow_push")
    hard = run.contexts("push")
    run = run_expert(TASK, "shifted", "slow_push")
    soft = run.contexts("push")
    assert hard[:, 0].mean() - soft[:, 0].mean() > 0.8


def test_a_different_book_in_view_and_in_words():
    a = KvmObsolescenceEnv(task=TASK, variant="prior")
    b = KvmObsolescenceEnv(task=TASK, variant="shifted")
    obs_a, _ = a.reset(seed=2)
    obs_b, _ = b.reset(seed=2)
    assert set(obs_a) == {"pixels", "agent_pos", "context"}
    assert np.abs(obs_a["pixels"]["front"].astype(float) - obs_b["pixels"]["front"].astype(float)).mean() > 0
    assert "paperback" in b.task_description and "hardcover" in a.task_description
    with pytest.raises(ValueError, match="no skill"):
        a.scenario.expert("throw")


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_slow_push_runs_at_its_speed_for_ten_steps_before_it_meets_the_book(seed):
    """The skill learned from the slow push meets the book at the push's speed only when the demonstration has
    settled into that speed well before contact."""
    env = KvmObsolescenceEnv(task=TASK, variant="shifted")
    env.reset(seed=seed)
    expert = env.scenario.expert("slow_push")
    xs = []
    for _ in range(env._max_episode_steps):
        env.step(expert.act(env.physics))
        xs.append(float(env.physics.sensors.arm_position(env.data)[0]))
        if env.scenario.peak_force > 0.0:
            break
    assert env.scenario.peak_force > 0.0, "the pusher never met the book"
    steps = np.diff(xs)[::-1]  # from the contact backwards
    steady = int(np.argmax(np.abs(steps - 0.004) > 0.0005))  # steps at the push's 4 mm before contact
    assert steady >= 10
