"""`lerobot-kvm record`: scripted-expert episodes -> LeRobotDataset v3."""

import argparse
import json
from pathlib import Path

from ..datasets.recorder import RecordingSpec, RecordItem, record_dataset
from ..envs.catalogue import resolve_tasks, scenario_info


def _split(text: str) -> list[str]:
    return [t.strip() for t in text.split(",") if t.strip()]


def spec_from_args(args: argparse.Namespace) -> RecordingSpec:
    if args.spec:
        spec = RecordingSpec.from_json(args.spec)
        if args.seed is not None:
            spec.seed = args.seed
        return spec
    if not args.scenarios:
        raise ValueError("give --spec FILE or --scenarios (ids, categories or 'all')")
    items = []
    for sid in resolve_tasks(args.scenarios):
        info = scenario_info(sid)
        aliases = {"prior": info.prior_skill, "safe": info.safe_skill}
        for variant in _split(args.variants):
            for skill in _split(args.skills):
                items.append(RecordItem(sid, variant, aliases.get(skill, skill), args.episodes, args.instruction))
    return RecordingSpec(name=args.name or Path(args.root).name, items=items, seed=args.seed or 0)


def run(args: argparse.Namespace) -> int:
    spec = spec_from_args(args)
    summary = record_dataset(spec, args.root, repo_id=args.repo_id, overwrite=args.overwrite)
    print(json.dumps(summary, indent=2))
    return 0


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--spec", help="JSON recording spec (see datasets/specs/)")
    p.add_argument("--scenarios", help="scenario ids, categories (A,B,C) or 'all', comma separated")
    p.add_argument("--variants", default="prior", help="comma list of variants (prior, shifted, control)")
    p.add_argument("--skills", default="prior", help="comma list of skills; 'prior'/'safe' name each scenario's own")
    p.add_argument("--episodes", type=int, default=20, help="episodes per scenario x variant x skill")
    p.add_argument("--instruction", default="variant", choices=["variant", "skill"])
    p.add_argument("--name", help="dataset name (default: the root's folder name)")
    p.add_argument("--root", required=True, help="output dataset root (must not exist unless --overwrite)")
    p.add_argument("--repo-id", help="repo id stored in the dataset (default local/<name>)")
    p.add_argument("--seed", type=int, default=None)
    p.add_argument("--overwrite", action="store_true")
    p.set_defaults(func=run)
