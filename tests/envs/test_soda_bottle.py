import numpy as np
import pytest

from lerobot_kvm.envs.env import KvmObsolescenceEnv

TASK = "soda_bottle"


def bottle_tilt(env) -> float:
    return float(np.degrees(np.arccos(np.clip(env.data.body("bottle").xmat[8], -1, 1))))


@pytest.mark.parametrize("seed", [0, 1])
def test_fast_push_slides_a_full_bottle_and_knocks_an_empty_one_over(run_expert, seed):
    run = run_expert(TASK, "prior", "fast_push", seed)
    info, env = run.info, run.env
    assert info["is_success"] and not info["catastrophe"]
    assert bottle_tilt(env) < 8
    run = run_expert(TASK, "shifted", "fast_push", seed)
    info, env = run.info, run.env
    assert info["catastrophe"] and info["catastrophe_kind"] == "tip_over"
    assert not info["is_success"] and bottle_tilt(env) > 40


def test_slow_low_push_moves_the_empty_bottle_upright(run_expert):
    run = run_expert(TASK, "shifted", "slow_push")
    info, env = run.info, run.env
    assert info["is_success"] and not info["catastrophe"]
    assert bottle_tilt(env) < 8


def test_control_heavier_bottle_still_takes_the_fast_push(run_expert):
    info = run_expert(TASK, "control", "fast_push").info
    assert info["is_success"] and not info["catastrophe"]


def test_full_and_empty_bottles_push_back_differently(run_expert):
    """Rule 3: pushing the full bottle loads the wrist along the push far more than the empty one."""
    run = run_expert(TASK, "prior", "slow_push")
    full = run.contexts("push")
    run = run_expert(TASK, "shifted", "slow_push")
    empty = run.contexts("push")
    assert full[:, 0].mean() - empty[:, 0].mean() > 0.8


def test_a_different_bottle_in_view_and_in_words():
    a = KvmObsolescenceEnv(task=TASK, variant="prior")
    b = KvmObsolescenceEnv(task=TASK, variant="shifted")
    obs_a, _ = a.reset(seed=3)
    obs_b, _ = b.reset(seed=3)
    assert set(obs_a) == {"pixels", "agent_pos", "context"}
    diff = np.abs(obs_a["pixels"]["front"].astype(float) - obs_b["pixels"]["front"].astype(float)).mean()
    assert diff > 0
    assert a.task_description != b.task_description and "empty" in b.task_description
    with pytest.raises(ValueError, match="no skill"):
        a.scenario.expert("kick")
