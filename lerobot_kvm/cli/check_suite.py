"""`lerobot-kvm check-suite`: measure every scenario against the suite's acceptance thresholds.

It is a measurement, not a gate: the exit code is 0 whatever the result, and the summary line
says how many scenarios pass.
"""

import argparse
import json
from pathlib import Path

from ..envs.catalogue import resolve_tasks
from ..evaluation.suite_check import (
    MAX_FALSE_ALARM,
    MIN_PARTICLE_STEPS_PER_S,
    MIN_RESCUE,
    MIN_STEPS_PER_S,
    RESCUE_LATENCY,
    check_suite,
)
from .table import results_table

# (header, row key, format); rates are fractions of episodes
COLUMNS = (
    ("scenario", "id", "{}"),
    ("cat", "category", "{}"),
    ("pp succ", "prior_on_prior_success", "{:.2f}"),
    ("pp cat", "prior_on_prior_catastrophe", "{:.2f}"),
    ("ps cat", "prior_on_shifted_catastrophe", "{:.2f}"),
    ("ss succ", "safe_on_shifted_success", "{:.2f}"),
    ("ss cat", "safe_on_shifted_catastrophe", "{:.2f}"),
    ("ctrl succ", "control_prior_skill_success", "{:.2f}"),
    ("ctrl cat", "control_prior_skill_catastrophe", "{:.2f}"),
    ("img diff", "reset_image_diff", "{:.2f}"),
    ("steps/s", "env_steps_per_s", "{:.0f}"),
    ("fa", "false_alarm", "{:.2f}"),
    ("det", "detection_step", "{:.0f}"),
    ("last", "last_rescue_step", "{:.0f}"),
    ("harm", "harm_step", "{:.0f}"),
    ("r0", "rescue_0", "{:.2f}"),
    ("r2", "rescue_2", "{:.2f}"),
    ("r5", "rescue_5", "{:.2f}"),
    ("rescue", "rescue_rule", "{}"),
)
LEGEND = (
    "pp = prior skill on prior variant, ps = prior skill on shifted, ss = safe skill on shifted,\n"
    "ctrl = prior skill on control; succ/cat = success/catastrophe rate over the episodes;\n"
    "fa = prior-variant runs whose context leaves the envelope; det / last / harm = median step of detection, of the\n"
    "last takeover that still rescues, of the catastrophe (prior skill on shifted); rN = rescued with the safe expert\n"
    f"taking over N steps after detection; rescue (A/B) = r{RESCUE_LATENCY} >= {MIN_RESCUE:.2f} at fa <= "
    f"{MAX_FALSE_ALARM:.2f}"
)
RULE = {True: "pass", False: "fail", None: "-"}


def format_table(report: dict) -> str:
    rows = [{**row, "rescue_rule": RULE[row["passes"]["rescue"]]} for row in report["scenarios"]]
    return results_table(rows, COLUMNS)


def run(args: argparse.Namespace) -> int:
    report = check_suite(resolve_tasks(args.tasks), episodes=args.episodes, seed=args.seed)
    print(format_table(report))
    print(LEGEND)
    particle = [row["id"] for row in report["scenarios"] if row["particle_scene"]]
    if particle:
        print(
            f"particle scenes (speed bar {MIN_PARTICLE_STEPS_PER_S:.0f} instead of {MIN_STEPS_PER_S:.0f}): "
            + ", ".join(particle)
        )
    if args.json:
        path = Path(args.json)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(report, indent=2) + "\n")
        print(f"wrote {path}")
    print(
        f"{report['n_pass']}/{report['n_scenarios']} scenarios pass "
        f"({report['episodes']} episodes per run, seed {report['seed']}, {report['wall_time_s']:.0f} s)"
    )
    return 0


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--episodes", type=int, default=20, help="episodes per scenario x variant x skill")
    p.add_argument("--seed", type=int, default=0, help="episode seeds are seed, seed+1, ...")
    p.add_argument("--tasks", default="all", help="scenario ids, categories (A,B,C) or 'all', comma separated")
    p.add_argument("--json", help="also write the full report to this JSON file")
    p.set_defaults(func=run)
