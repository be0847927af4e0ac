"""`lerobot-kvm overhead`: per-step latency with the KVM off / on with the gate closed / on with it forced open."""

import argparse
import json
from pathlib import Path


def run(args: argparse.Namespace) -> int:
    import torch
    from lerobot.configs.policies import PreTrainedConfig

    from ..evaluation.overhead import give_failures, measure_overhead, observation_inputs
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
    failures = give_failures(policy, path, args.failures.split(","), args.seed) if args.failures else []
    batch, source = observation_inputs(policy, path, args.task, args.variant, args.seed)
    result = measure_overhead(policy, batch, steps=args.steps, warmup=args.warmup, block=args.block)
    result.update(policy_path=str(path), inputs=source, feedback=failures, failure_memory=len(policy.kvm.fail_online))
    text = json.dumps(result, indent=2)
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(text + "\n")
    print(text)
    return 0


def add_arguments(p: argparse.ArgumentParser) -> None:
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
    p.add_argument("--device", help="override the checkpoint's device (e.g. cpu)")
    p.add_argument("--threads", type=int, default=0, help="torch threads (0: torch's default)")
    p.set_defaults(func=run)
