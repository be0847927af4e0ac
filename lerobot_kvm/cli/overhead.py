"""`lerobot-kvm overhead`: per-step latency with the KVM off / on with the gate closed / on with it forced open."""

import argparse
import json
from pathlib import Path

from .kvm_check import lag_list


def observation_inputs(
    policy, policy_path: Path, task: str, variant: str, seed: int, context_lags: tuple[int, ...] = ()
) -> tuple[dict, str]:
    """A real observation of the scenario through the checkpoint's preprocessor (random inputs without one); the
    environment senses with `context_lags`, as the checkpoint's dataset was recorded."""
    import torch

    if any(policy_path.glob("policy_preprocessor*.json")):
        from ..envs.env import KvmObsolescenceEnv
        from ..kvm.evaluation import observation_batch, policy_processors

        preprocessor, _ = policy_processors(policy, policy_path)
        env = KvmObsolescenceEnv(task=task, variant=variant, context_lags=context_lags)
        try:
            obs, _ = env.reset(seed=seed)
            return preprocessor(observation_batch(obs, env.task_description)), f"{task}/{variant} observation"
        finally:
            env.close()
    gen = torch.Generator().manual_seed(seed)
    batch = {k: torch.rand(1, *ft.shape, generator=gen) for k, ft in policy.config.input_features.items()}
    batch["task"] = ["pick up the object"]
    return {k: v.to(policy.config.device) if hasattr(v, "to") else v for k, v in batch.items()}, "random inputs"


def give_failures(
    policy, policy_path: Path, scenarios: list[str], seed: int, context_lags: tuple[int, ...] = ()
) -> list[dict]:
    """One attempt of the policy on each scenario's shifted variant, its outcome given back through the feedback
    API, as in deployment: a failed attempt puts its contexts in the KVM's failure memory, so that the gate-open
    step is timed with the nearest-neighbour risk model searching them (a skill without failures has none)."""
    from ..envs.env import KvmObsolescenceEnv
    from ..kvm.evaluation import policy_processors, run_attempt

    if not any(policy_path.glob("policy_preprocessor*.json")):
        raise FileNotFoundError(f"--failures runs the policy in the scenarios: {policy_path} has no processors")
    pre, post = policy_processors(policy, policy_path)
    given = []
    for scenario in scenarios:
        env = KvmObsolescenceEnv(task=scenario, variant="shifted", context_lags=context_lags)
        try:
            attempt = run_attempt(policy, env, pre, post, seed=seed)
        finally:
            env.close()
        policy.kvm_feedback(attempt["outcome"], attempt["trace"])
        given.append({"scenario": scenario, "outcome": attempt["outcome"], "steps": attempt["steps"]})
    return given


def run(args: argparse.Namespace) -> int:
    import torch
    from lerobot.configs.policies import PreTrainedConfig

    from ..kvm.overhead import measure_overhead
    from ..policy import CodaKvmPolicy

    if args.threads:
        torch.set_num_threads(args.threads)
    torch.manual_seed(args.seed)  # the feedback's gradient steps draw their batches: the same seed, the same memory
    path = Path(args.policy_path)
    if not (path / "model.safetensors").exists():
        raise FileNotFoundError(f"{path} is not a coda_kvm checkpoint (no model.safetensors)")
    config = PreTrainedConfig.from_pretrained(path)
    config.device = args.device or config.device
    policy = CodaKvmPolicy.from_pretrained(path, config=config)
    lags = args.context_lags
    failures = give_failures(policy, path, args.failures.split(","), args.seed, lags) if args.failures else []
    batch, source = observation_inputs(policy, path, args.task, args.variant, args.seed, lags)
    result = measure_overhead(policy, batch, steps=args.steps, warmup=args.warmup, block=args.block)
    result.update(policy_path=str(path), inputs=source, feedback=failures, failure_memory=len(policy.kvm.fail_online))
    text = json.dumps(result, indent=2)
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(text + "\n")
    print(text)
    return 0


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("overhead", help="KVM latency overhead: off vs gate closed vs gate open (ratios)")
    p.add_argument("--policy-path", required=True, help="a coda_kvm checkpoint (pretrained_model directory)")
    p.add_argument("--json", help="write the measurement here")
    p.add_argument("--steps", type=int, default=200, help="model calls per mode")
    p.add_argument("--warmup", type=int, default=10)
    p.add_argument("--block", type=int, default=10, help="calls per mode before switching to the next")
    p.add_argument("--task", default="egg_vs_stone", help="scenario providing the observation")
    p.add_argument("--variant", default="prior")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument(
        "--failures",
        default="",
        help="comma-separated scenarios: before timing, one attempt on each one's shifted variant with its outcome "
        "given as feedback (puts failures in the KVM's memory, as after deployment)",
    )
    p.add_argument(
        "--context-lags",
        type=lag_list,
        default=(),
        help="the environment's context lags the checkpoint's dataset was recorded with (e.g. 1,2,4,8)",
    )
    p.add_argument("--device", help="override the checkpoint's device (e.g. cpu)")
    p.add_argument("--threads", type=int, default=0, help="torch threads (0: torch's default)")
    p.set_defaults(func=run)
