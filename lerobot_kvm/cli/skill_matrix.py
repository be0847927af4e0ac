"""`lerobot-kvm skill-matrix`: each skill of a coda_kvm checkpoint forced alone on each scenario variant."""

import argparse
import json
import time
from pathlib import Path


def run(args: argparse.Namespace) -> int:
    from ..benchmark.protocol import load_policy
    from ..envs.catalogue import resolve_tasks
    from ..evaluation.skill_matrix import format_matrix, own_variant_summary, skill_matrix

    path = Path(args.policy_path)
    if not (path / "model.safetensors").exists():
        raise FileNotFoundError(f"{path} is not a coda_kvm checkpoint (no model.safetensors)")
    scenarios = resolve_tasks(args.tasks)
    policy, pre, post = load_policy("coda_prompt", path, device=args.device)  # the KVM off: skills as trained
    start = time.time()
    matrix = skill_matrix(policy, pre, post, scenarios, args.episodes, args.seed, own_only=args.own)
    matrix |= {"policy_path": str(path), "wall_time_s": time.time() - start, "own": own_variant_summary(matrix)}
    print(format_matrix(matrix))
    print("cells: success/catastrophe in % of episodes; each skill forced alone (weight 1, every other 0)")
    own = matrix["own"]
    if own["mean"] is not None:
        weakest = min(own["skills"], key=own["skills"].get)
        print(
            f"own variant (prior skill: prior, safe skill: shifted): mean {100 * own['mean']:.0f} %, "
            f"min {100 * own['min']:.0f} % ({weakest}), {len(own['skills'])} skills; {matrix['wall_time_s']:.0f} s"
        )
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(matrix, indent=2) + "\n")
        print(f"wrote {args.json}")
    return 0


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--policy-path", required=True, help="a coda_kvm checkpoint (pretrained_model directory)")
    p.add_argument("--tasks", default="all", help="scenario ids, categories (A,B,C) or 'all', comma separated")
    p.add_argument("--episodes", type=int, default=10, help="episodes per skill and scenario variant")
    p.add_argument("--seed", type=int, default=0, help="episode seeds are seed, seed+1, ...")
    p.add_argument(
        "--own", action="store_true", help="run a stage skill on its own scenario only (the pretraining skill on all)"
    )
    p.add_argument("--device", default="cpu")
    p.add_argument("--json", help="also write the matrix to this JSON file")
    p.set_defaults(func=run)
