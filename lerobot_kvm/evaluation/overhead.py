"""Per-step latency of the policy with the KVM off, on with the gate closed, and on with the gate forced open.

All three modes run in one process on the same inputs, interleaved in blocks (off, closed, open, off, ...) so
that load drifts on a shared machine hit every mode alike; the statistic is the median per-call latency. The
paired ratios divide each block's median by the KVM-off block's of the same rotation and take the median over
rotations: a drift slower than one rotation cancels in them, where it only shifts the pooled medians.

* model call: one `predict_action_chunk` (query, CODA relevances, KVM assessment, fused prompt, backbone) --
  the unit the paper's overhead (App. H.2) is about; the acceptance ratios are taken here.
* control step: one `select_action` averaged over a full action chunk (one model call per `n_action_steps`
  steps, plus the KVM's per-step trace recording) -- what the per-control-step overhead targets are about; its paired
  ratios are taken the same way, over the chunks timed in each rotation.
"""

import statistics
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import torch

from ..envs.env import KvmObsolescenceEnv
from .rollouts import observation_batch, policy_processors, run_attempt

MODES = ("off", "closed", "open")


def _set_mode(policy: Any, mode: str) -> None:
    policy.config.kvm.enabled = mode != "off"
    policy.kvm.set_gate_override(None if mode == "off" else mode)


def paired_ratio(blocks: list[float], off_blocks: list[float]) -> float:
    """Median over rotations of a mode's block median relative to the KVM-off block median of the same rotation."""
    return statistics.median(b / o for b, o in zip(blocks, off_blocks, strict=True))


def _synchronizer(device: torch.device) -> Callable[[], None]:
    """An accelerator runs kernels asynchronously: a call has taken its time once its device is idle again."""
    if device.type == "cuda":
        return lambda: torch.cuda.synchronize(device)
    return lambda: None


def _time_calls(fn: Callable[[], Any], n: int, sync: Callable[[], None]) -> list[float]:
    out = []
    for _ in range(n):
        sync()
        t = time.perf_counter()
        fn()
        sync()
        out.append(time.perf_counter() - t)
    return out


@torch.no_grad()
def measure_overhead(
    policy: Any, batch: dict[str, Any], steps: int = 200, warmup: int = 10, block: int = 10
) -> dict[str, Any]:
    """Latencies (ms) and ratios to the KVM-off step time; restores the policy's KVM settings afterwards."""
    if steps < block:
        raise ValueError(f"steps ({steps}) must be >= block ({block})")
    enabled, override = policy.config.kvm.enabled, policy.kvm.gate_override
    policy.eval()
    calls: dict[str, list[float]] = {m: [] for m in MODES}
    control: dict[str, list[float]] = {m: [] for m in MODES}
    blocks: dict[str, list[float]] = {m: [] for m in MODES}  # per rotation: the block's median call latency
    step_blocks: dict[str, list[float]] = {m: [] for m in MODES}  # per rotation: the median control step
    n_action = policy.config.n_action_steps
    device = policy.query_fingerprint.device
    sync = _synchronizer(device)
    gate_open: dict[str, bool] = {}
    try:
        for mode in MODES:
            _set_mode(policy, mode)
            for _ in range(warmup):
                policy.predict_action_chunk(batch)
            telemetry = policy.kvm_telemetry
            gate_open[mode] = bool(telemetry.gate.any()) if (mode != "off" and telemetry is not None) else False

        def chunk_of_steps() -> None:
            policy.reset()
            for _ in range(n_action):
                policy.select_action(batch)

        for _ in range(steps // block):
            for mode in MODES:
                _set_mode(policy, mode)
                timed = _time_calls(lambda: policy.predict_action_chunk(batch), block, sync)
                calls[mode] += timed
                blocks[mode].append(statistics.median(timed))
                steps_timed = [t / n_action for t in _time_calls(chunk_of_steps, max(1, block // n_action), sync)]
                control[mode] += steps_timed
                step_blocks[mode].append(statistics.median(steps_timed))
    finally:
        policy.config.kvm.enabled = enabled
        policy.kvm.set_gate_override(override)
        policy.reset()
    med = {m: statistics.median(calls[m]) * 1e3 for m in MODES}
    ctl = {m: statistics.median(control[m]) * 1e3 for m in MODES}
    return {
        "model_call_ms": med,
        "control_step_ms": ctl,
        "ratio_gate_closed": med["closed"] / med["off"],
        "ratio_gate_open": med["open"] / med["off"],
        "paired_ratio_gate_closed": paired_ratio(blocks["closed"], blocks["off"]),
        "paired_ratio_gate_open": paired_ratio(blocks["open"], blocks["off"]),
        "control_step_ratio_gate_closed": ctl["closed"] / ctl["off"],
        "control_step_ratio_gate_open": ctl["open"] / ctl["off"],
        "paired_control_step_ratio_gate_closed": paired_ratio(step_blocks["closed"], step_blocks["off"]),
        "paired_control_step_ratio_gate_open": paired_ratio(step_blocks["open"], step_blocks["off"]),
        "gate_open_check": gate_open,
        "calls_per_mode": len(calls["off"]),
        "n_skills": policy.n_skills,
        "batch_size": int(next(v for v in batch.values() if isinstance(v, torch.Tensor)).shape[0]),
        "threads": torch.get_num_threads(),
        "device": str(device),
    }


def observation_inputs(policy: Any, policy_path: Path, task: str, variant: str, seed: int) -> tuple[dict, str]:
    """A real observation of the scenario through the checkpoint's preprocessor (random inputs without one)."""
    if any(policy_path.glob("policy_preprocessor*.json")):
        preprocessor, _ = policy_processors(policy, policy_path)
        env = KvmObsolescenceEnv(task=task, variant=variant)
        try:
            obs, _ = env.reset(seed=seed)
            return preprocessor(observation_batch(obs, env.task_description)), f"{task}/{variant} observation"
        finally:
            env.close()
    gen = torch.Generator().manual_seed(seed)
    batch = {k: torch.rand(1, *ft.shape, generator=gen) for k, ft in policy.config.input_features.items()}
    batch["task"] = ["pick up the object"]
    return {k: v.to(policy.config.device) if hasattr(v, "to") else v for k, v in batch.items()}, "random inputs"


def give_failures(policy: Any, policy_path: Path, scenarios: list[str], seed: int) -> list[dict]:
    """One attempt of the policy on each scenario's shifted variant, its outcome given back through the feedback
    API, as in deployment: a failed attempt puts its contexts in the KVM's failure memory and trains E_theta, so
    that the gate-open step is timed on a KVM that has met failures."""
    if not any(policy_path.glob("policy_preprocessor*.json")):
        raise FileNotFoundError(f"--failures runs the policy in the scenarios: {policy_path} has no processors")
    pre, post = policy_processors(policy, policy_path)
    given = []
    for scenario in scenarios:
        env = KvmObsolescenceEnv(task=scenario, variant="shifted")
        try:
            attempt = run_attempt(policy, env, pre, post, seed=seed)
        finally:
            env.close()
        policy.kvm_feedback(attempt["outcome"], attempt["trace"])
        given.append({"scenario": scenario, "outcome": attempt["outcome"], "steps": attempt["steps"]})
    return given
