"""`lerobot-kvm catalogue`: write the scenario table (docs/scenarios.md) from the registry."""

import argparse
from pathlib import Path

from ..envs.catalogue import catalogue_markdown, resolve_tasks


def run(args: argparse.Namespace) -> int:
    ids = resolve_tasks(args.tasks)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(catalogue_markdown(ids))
    print(f"wrote {out} ({len(ids)} scenarios)")
    return 0


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", default="docs/scenarios.md")
    p.add_argument("--tasks", default="all", help="scenario ids, categories (A,B,C) or 'all', comma separated")
    p.set_defaults(func=run)
