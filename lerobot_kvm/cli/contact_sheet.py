"""`lerobot-kvm contact-sheet`: render every scenario's prior/shifted story into one PNG to check by eye."""

import argparse
from pathlib import Path

from ..envs.catalogue import resolve_tasks
from ..evaluation.contact_sheet import contact_sheet


def run(args: argparse.Namespace) -> int:
    ids = resolve_tasks(args.tasks)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    contact_sheet(ids, seed=args.seed, size=args.size).save(out)
    print(f"wrote {out} ({len(ids)} scenarios)")
    return 0


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", default="docs/contact_sheet.png")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--tasks", default="all", help="scenario ids, categories (A,B,C) or 'all', comma separated")
    p.add_argument("--size", type=int, default=160, help="panel size in pixels")
    p.set_defaults(func=run)
