"""`lerobot-kvm walkthrough`: record -> `lerobot-train` -> `lerobot-eval` on egg_vs_stone, then print the result.

Each stage is the real tool a user would run; the exact commands are printed so they can be
copied and varied.
"""

import argparse
import json
import shutil
import time
from dataclasses import asdict
from pathlib import Path

from ..benchmark.lerobot_commands import eval_command, run_logged, train_command
from ..benchmark.resume import check_settings, differences
from ..datasets.check import check_dataset
from ..datasets.labels import load_labels
from ..datasets.recorder import RecordingSpec, record_dataset

DEFAULT_SPEC = Path(__file__).resolve().parents[2] / "datasets" / "specs" / "egg_vs_stone_demo.json"


def check_recording(root: Path, spec: RecordingSpec) -> None:
    """Refuse a dataset recorded from another spec (or other `--episodes`): training on it would silently use
    other episodes than asked for."""
    changed = differences(load_labels(root)["spec"], asdict(spec))
    if changed:
        raise ValueError(
            f"dataset {root} was recorded with other settings ({changed}): delete it or give --dataset-root"
        )


def run(args: argparse.Namespace) -> int:
    start = time.time()
    for option in ("steps", "batch_size", "eval_episodes", "episodes"):
        value = getattr(args, option)
        if value is not None and value < 1:  # refused before anything is recorded, trained or written
            raise ValueError(f"--{option.replace('_', '-')} must be >= 1, got {value}")
    out = Path(args.output_dir)
    spec = RecordingSpec.from_json(args.spec)
    if args.episodes is not None:
        for item in spec.items:
            item.episodes = args.episodes
    dataset_root = Path(args.dataset_root or f"datasets/{spec.name}")
    repo_id = f"local/{spec.name}"
    reuse = dataset_root.exists()
    if reuse:  # checked before the settings are recorded, which would refuse the rerun with another --dataset-root
        check_dataset(dataset_root)
        check_recording(dataset_root, spec)
    if args.fresh:
        shutil.rmtree(out, ignore_errors=True)
    trained_with = {"dataset_root": str(dataset_root), "recording": asdict(spec), "steps": args.steps}
    trained_with |= {"batch_size": args.batch_size, "seed": args.seed}
    check_settings(out, trained_with, "a walkthrough's policy", "pass --fresh")
    if reuse:
        print(f"[1/3] reusing recorded dataset {dataset_root}")
    else:
        print(f"[1/3] recording {dataset_root}")
        record_dataset(spec, dataset_root, repo_id=repo_id)

    train_dir = out / "train"
    policy_path = train_dir / "checkpoints" / "last" / "pretrained_model"
    if not policy_path.exists():
        print("[2/3] training coda_kvm with lerobot-train")
        shutil.rmtree(train_dir, ignore_errors=True)
        run_logged(
            train_command(dataset_root, repo_id, train_dir, args.steps, args.batch_size, args.seed, device=args.device)
        )
    else:
        print(f"[2/3] reusing trained policy {policy_path}")

    print("[3/3] evaluating with lerobot-eval")
    eval_dir = out / f"eval_{args.variant}"
    shutil.rmtree(eval_dir, ignore_errors=True)
    run_logged(
        eval_command(
            policy_path, eval_dir, "egg_vs_stone", args.variant, args.eval_episodes, args.seed, device=args.device
        )
    )
    info = json.loads((eval_dir / "eval_info.json").read_text())
    overall = info["overall"]
    catastrophes = sum(r < 0 for task in info["per_task"] for r in task["metrics"]["sum_rewards"])
    print(
        f"\negg_vs_stone ({args.variant}): success {overall['pc_success']:.1f}%, {catastrophes} catastrophes over "
        f"{overall['n_episodes']} episodes  [policy: {policy_path}]  ({time.time() - start:.0f} s total)"
    )
    return 0


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--spec", default=str(DEFAULT_SPEC), help="recording spec for the demo dataset")
    p.add_argument("--dataset-root", help="where the dataset lives (default datasets/<spec name>)")
    p.add_argument("--output-dir", default="outputs/walkthrough")
    p.add_argument("--episodes", type=int, help="override episodes per spec item")
    p.add_argument("--steps", type=int, default=800)
    p.add_argument("--batch-size", type=int, default=32)
    p.add_argument("--eval-episodes", type=int, default=20)
    p.add_argument("--variant", default="prior")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--device", default="cpu", help="torch device of lerobot-train and lerobot-eval (e.g. cuda)")
    p.add_argument("--fresh", action="store_true", help="retrain and re-evaluate even if outputs exist")
    p.set_defaults(func=run)
