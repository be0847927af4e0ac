"""`lerobot-kvm train-continual`: learn a task sequence stage by stage with `lerobot-train`, evaluate every
learned task after every stage with `lerobot-eval`, and write the CL metrics (see `benchmark.continual`)."""

import argparse
import shlex
from pathlib import Path

from ..benchmark.continual import ContinualRun, SequenceConfig


def run(args: argparse.Namespace) -> int:
    config = SequenceConfig.from_json(args.config)
    if args.dataset_root:
        config.dataset_root = args.dataset_root
    only = [m.strip() for m in args.methods.split(",") if m.strip()] if args.methods else None
    launcher = shlex.split(args.launcher) if args.launcher else []
    report = ContinualRun(config, Path(args.output_dir), launcher, args.config, only, args.device).run()
    print()
    print((Path(args.output_dir) / "cl_report.md").read_text())
    print(f"results: {Path(args.output_dir) / 'cl_results.json'}  ({report['wall_time_s'] / 60:.1f} min)")
    return 0


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--config", required=True, help="sequence config (see configs/cl_*.json)")
    p.add_argument("--output-dir", required=True, help="where stages, evaluations and results go (resumable)")
    p.add_argument("--dataset-root", help="the sequence's dataset (default datasets/kvm_cl_<name>; recorded if absent)")
    p.add_argument("--methods", help="comma list: run only these methods now (results of the others are kept)")
    p.add_argument(
        "--launcher",
        help="multi-process launcher prefixed to every lerobot-train, e.g. 'torchrun --nproc_per_node=2'",
    )
    p.add_argument("--device", default="cpu", help="torch device of every lerobot-train and lerobot-eval (e.g. cuda)")
    p.set_defaults(func=run)
