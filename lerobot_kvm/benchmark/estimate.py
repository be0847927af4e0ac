"""What a benchmark invocation costs, printed before it starts: the pool's `lerobot-train` steps and `lerobot-eval`
episodes, and the (method, run) challenge units shared among the workers.

The per-step and per-unit costs are measurements on 2 CPU cores (docs/benchmark.md, Cost); on other machines
the estimate is only a scale. Work an earlier invocation finished is reused and makes the run shorter; a stage that
trains on because its skill is not learned yet (`MethodSpec.max_steps_per_stage`) makes it longer.
"""

from collections.abc import Sequence
from dataclasses import dataclass

from .continual import MethodSpec, SequenceConfig

# `lerobot-train` seconds per step by policy type, at the shipped sequences' batch sizes: coda_kvm from the default
# pool of 2026-11-27 (one torch thread beside other work), ACT from the full pool's joint run (3300 steps in 17 min),
# Diffusion Policy from its measured step (docs/benchmark.md, Cost).
TRAIN_STEP_S = {"coda_kvm": 0.33, "act": 0.31, "diffusion": 0.43}
EVAL_EPISODE_S = 1.0  # one `lerobot-eval` episode of a sequence's evaluation after a stage
# One episode scoring a stage's saved checkpoint, in process (no `lerobot-eval` start-up): the default pool's 1200
# selection episodes took 244 s with their checkpoint loads (2026-11-30).
SELECT_EPISODE_S = 0.2
RECORD_EPISODE_S = 0.3  # one scripted-expert episode recorded into the sequence's dataset (when it is absent)
# Seconds per challenge unit (one scenario in one pass: attempts, feedback, controls, probes) by method, one worker.
UNIT_S = {"act": 25.6, "diffusion": 75.0, "no_energy_model": 11.2, "no_smart_gate": 9.2, "coda_prompt": 5.1}
OTHER_UNIT_S = 7.7  # the other validity rows and the oracles, as `coda_kvm`


@dataclass(frozen=True)
class Estimate:
    recorded: int
    train_steps: int
    eval_episodes: int
    selection_episodes: int
    units: int
    pool_s: float
    units_s: float
    workers: int

    def line(self) -> str:
        pool = (
            f"pool {self.pool_s / 60:.0f} min ({self.recorded} episodes recorded, {self.train_steps} training "
            f"steps, {self.eval_episodes} evaluation and {self.selection_episodes} checkpoint-selection episodes)"
        )
        units = f"challenges {self.units_s / 60:.0f} min ({self.units} units on {self.workers} workers)"
        return f"estimated time (2 CPU cores, from scratch): {pool}, {units}; finished work is reused"


def method_cost(method: MethodSpec, sequence: SequenceConfig) -> tuple[int, int, int]:
    """(training steps, evaluation episodes, checkpoint-selection episodes) of one sequence method: pretraining,
    then one run per stage (each followed by the selection of its checkpoint when the method selects, and by an
    evaluation of every task learned so far) or one joint run evaluated once."""
    n = len(sequence.tasks)
    steps = method.pretrain_steps if sequence.pretrain_tasks else 0
    if method.mode == "joint":
        return steps + method.steps_per_stage, n * sequence.eval_episodes, 0
    saved = -(-method.steps_per_stage // method.select_every) if method.select_every else 0  # the last step included
    return (
        steps + n * method.steps_per_stage,
        n * (n + 1) // 2 * sequence.eval_episodes,
        n * saved * sequence.select_episodes,
    )


def estimate(
    sequence: SequenceConfig,
    pool_methods: Sequence[str],
    methods: Sequence[str],
    runs: int,
    passes: int,
    n_scenarios: int,
    workers: int,
) -> Estimate:
    known = {m.name: m for m in sequence.methods}
    recorded = len(sequence.pretrain_tasks) * sequence.pretrain_episodes_per_task
    recorded += len(sequence.tasks) * sequence.episodes_per_task
    steps = episodes = selecting = 0
    pool_s = recorded * RECORD_EPISODE_S
    for name in pool_methods:
        spec = known[name]
        s, e, c = method_cost(spec, sequence)
        steps, episodes, selecting = steps + s, episodes + e, selecting + c
        pool_s += s * TRAIN_STEP_S[spec.policy] + e * EVAL_EPISODE_S + c * SELECT_EPISODE_S
    units = len(methods) * runs * passes * n_scenarios
    unit_s = sum(UNIT_S.get(m, OTHER_UNIT_S) for m in methods) * runs * passes * n_scenarios
    lanes = max(1, min(workers, len(methods) * runs))
    return Estimate(recorded, steps, episodes, selecting, units, pool_s, unit_s / lanes, lanes)
