"""`lerobot-kvm benchmark`: grow the skill pool, run the challenge protocol for every method, write
`results.json`, `report.md` and `plots/` (see `benchmark.protocol`)."""

import argparse
import os
import shlex
from dataclasses import replace
from pathlib import Path

from ..benchmark.protocol import Benchmark, BenchmarkConfig


def run(args: argparse.Namespace) -> int:
    overrides: dict = {}
    if args.methods is not None:
        overrides["methods"] = [m.strip() for m in args.methods.split(",") if m.strip()]
    if args.runs is not None:
        overrides["runs"] = args.runs
    if args.dataset_root:
        overrides["dataset_root"] = args.dataset_root
    # the config's own checks see the command line's values too, before anything is trained or written
    config = replace(BenchmarkConfig.from_json(args.config), **overrides)
    out = Path(args.output_dir)
    launcher = shlex.split(args.launcher) if args.launcher else []
    benchmark = Benchmark(config, out, args.config, launcher, device=args.device, workers=args.workers)
    print(benchmark.estimate().line(), flush=True)
    results = benchmark.run()
    print()
    print((out / "report.md").read_text())
    print(f"results: {out / 'results.json'}  ({results['wall_time_s'] / 60:.1f} min)")
    return 0


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--config", required=True, help="benchmark config (see configs/benchmark_*.json)")
    p.add_argument("--output-dir", required=True, help="where the pool, episodes, results and report go (resumable)")
    p.add_argument("--methods", help="comma list overriding the config's methods")
    p.add_argument("--runs", type=int, help="override the number of runs R")
    p.add_argument("--dataset-root", help="the pool sequence's dataset (default datasets/kvm_cl_<sequence name>)")
    p.add_argument("--launcher", help="multi-process launcher for the pool's lerobot-train stages (as train-continual)")
    p.add_argument(
        "--device", default="cpu", help="torch device of the pool's training and of every method (e.g. cuda)"
    )
    p.add_argument(
        "--workers",
        type=int,
        default=os.cpu_count() or 1,
        help="worker processes for the independent (method, run) units (default: the number of cores)",
    )
    p.set_defaults(func=run)
