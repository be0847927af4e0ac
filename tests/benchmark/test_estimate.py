"""The benchmark's up-front estimate: the pool's steps and evaluation episodes counted from the sequence, and the
challenge units shared among the workers."""

import pytest

from lerobot_kvm.benchmark.continual import MethodSpec, SequenceConfig, TaskSpec
from lerobot_kvm.benchmark.estimate import (
    EVAL_EPISODE_S,
    OTHER_UNIT_S,
    RECORD_EPISODE_S,
    SELECT_EPISODE_S,
    TRAIN_STEP_S,
    UNIT_S,
    estimate,
    method_cost,
)


def sequence() -> SequenceConfig:
    return SequenceConfig(
        name="t",
        tasks=[TaskSpec("potato"), TaskSpec("drawer"), TaskSpec("egg_vs_stone")],
        pretrain_tasks=[TaskSpec("sponge")],
        methods=[
            MethodSpec("seq", steps_per_stage=100, pretrain_steps=300, select_every=40),
            MethodSpec("joint", policy="act", mode="joint", steps_per_stage=400, pretrain_steps=50),
        ],
        episodes_per_task=10,
        pretrain_episodes_per_task=5,
        eval_episodes=2,
        select_episodes=5,
    )


def test_a_sequential_method_trains_every_stage_and_evaluates_every_task_learned_so_far() -> None:
    seq = sequence()
    # checkpoints at steps 40, 80 and 100 of each stage, 5 selection episodes each
    assert method_cost(seq.methods[0], seq) == (300 + 3 * 100, (1 + 2 + 3) * 2, 3 * 3 * 5)
    assert method_cost(seq.methods[1], seq) == (50 + 400, 3 * 2, 0)


def test_the_estimate_adds_recording_training_evaluation_and_the_units_shared_by_the_workers() -> None:
    found = estimate(sequence(), ["seq", "joint"], ["coda_kvm", "act"], runs=2, passes=3, n_scenarios=4, workers=2)
    assert (found.recorded, found.train_steps, found.eval_episodes, found.units) == (35, 1050, 18, 48)
    assert found.selection_episodes == 45
    pool = 35 * RECORD_EPISODE_S + 600 * TRAIN_STEP_S["coda_kvm"] + 450 * TRAIN_STEP_S["act"] + 18 * EVAL_EPISODE_S
    pool += 45 * SELECT_EPISODE_S
    assert found.pool_s == pytest.approx(pool)
    assert found.units_s == pytest.approx((OTHER_UNIT_S + UNIT_S["act"]) * 2 * 3 * 4 / 2)
    assert "48 units on 2 workers" in found.line()
    alone = estimate(sequence(), ["seq"], ["coda_kvm"], runs=1, passes=1, n_scenarios=1, workers=8)
    assert alone.workers == 1  # one (method, run) unit keeps one worker busy, whatever the count
