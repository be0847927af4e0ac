"""`lerobot-kvm kvm-check`: the KVM's validity acceptance per scenario (one failure + feedback, then v).

A measurement, not a gate: the exit code is 0 whatever the result; the summary line says how many scenarios pass.
"""

import argparse
import json
from pathlib import Path

from ..envs.catalogue import resolve_tasks
from ..kvm.configuration import RISK_MODELS, KvmConfig
from .table import results_table

COLUMNS = (
    ("scenario", "id", "{}"),
    ("seed", "seed", "{:d}"),
    ("cat", "category", "{}"),
    ("failed attempt", "failed_attempt", "{}"),
    ("shift step", "shift_step", "{:.0f}"),
    ("fail steps", "failure_steps", "{:d}"),
    ("label rec", "label_recall", "{:.2f}"),
    ("label prec", "label_precision", "{:.2f}"),
    ("v prior", "v_prior_median", "{:.3f}"),
    ("v>0.9", "v_prior_above_0.9", "{:.2f}"),
    ("v shifted", "v_shifted_median", "{:.3f}"),
    ("v<tau_v", "v_shifted_below_tau_v", "{:.2f}"),
    ("AUROC", "auroc", "{:.3f}"),
    ("AUROC prior", "auroc_prior_skill", "{:.3f}"),
    ("NN ref", "neighbour_auroc", "{:.3f}"),
    ("NN code", "neighbour_auroc_code", "{:.3f}"),
    ("NN hist", "neighbour_auroc_history", "{:.3f}"),
    ("own steps", "own_shifted_steps", "{:d}"),
    ("AUROC own", "auroc_own_steps", "{:.3f}"),
    ("NN own", "neighbour_auroc_own_steps", "{:.3f}"),
    ("gate prior", "gate_rate_prior", "{:.3f}"),
    ("gate shifted", "gate_rate_shifted", "{:.2f}"),
)
LEGEND = (
    "v prior / v shifted = median validity of the prior skill in the prior-variant context / in the shifted context\n"
    "(the steps from the first one that senses contact and departs from the prior variant's context, same seed\n"
    "and skill);\n"
    "AUROC of 1 - v: prior skill in the shifted context vs. prior skill in the prior context and safe skill in\n"
    "the shifted context; AUROC prior: the prior skill's pairs only; NN ref: the same pairs scored by nearest\n"
    "neighbours in the sensed context from the same experience, the failed attempt and the demonstration cut at\n"
    "their shift steps (which the KVM is not told); NN code: the same on E_c's codes mu_c after the feedback;\n"
    "NN hist: the same on each context joined with a few earlier ones of its episode (HISTORY_LAGS);\n"
    "own: the same over the prior skill's own shifted steps only; fail steps = contexts the feedback learned as\n"
    "hazardous; label rec / prec: the share of the failed and the corrective attempts' shifted steps among them /\n"
    "of them among the shifted steps;\n"
    "gate = share of steps on which the smart gate opens"
)


SUMMARY_COLUMNS = (
    ("scenario", "id", "{}"),
    ("cat", "category", "{}"),
    ("seeds passed", "seeds_passed", "{}"),
    ("AUROC mean", "auroc_mean", "{:.3f}"),
    ("AUROC min", "auroc_min", "{:.3f}"),
    ("v prior min", "v_prior_min", "{:.3f}"),
    ("v shifted max", "v_shifted_max", "{:.3f}"),
    ("gate prior max", "gate_max", "{:.3f}"),
)


def summary_rows(summary: list[dict]) -> list[dict]:
    """The per-scenario summary as `results_table` rows: a check fails when it fails at any seed."""

    def pick(spread: dict | None, which: str) -> float | None:
        return None if spread is None else spread[which]

    return [
        {
            "id": s["id"],
            "category": s["category"],
            "seeds_passed": f"{s['seeds_passed']}/{s['seeds']}",
            "auroc_mean": pick(s["auroc"], "mean"),
            "auroc_min": pick(s["auroc"], "min"),
            "v_prior_min": pick(s["v_prior_median"], "min"),
            "v_shifted_max": pick(s["v_shifted_median"], "max"),
            "gate_max": pick(s["gate_rate_prior"], "max"),
            "passes": {name: n == s["seeds"] for name, n in s["checks_passed"].items()},
            "passed": s["passed"],
        }
        for s in summary
    ]


def seed_list(text: str) -> tuple[int, ...]:
    try:
        return tuple(int(s) for s in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"seeds must be comma-separated integers, got {text!r}") from None


def run(args: argparse.Namespace) -> int:
    report = load_report(Path(args.from_json)) if args.from_json else measure(args)
    seeds = report["seeds"]
    print(results_table(report["scenarios"], COLUMNS))
    print(LEGEND)
    if len(seeds) > 1:
        print()
        print(results_table(summary_rows(report["summary"]), SUMMARY_COLUMNS))
        print("over the seeds: v prior min = the lowest median, v shifted max = the highest; a check fails if it fails")
        print("at any seed")
    if args.json:
        path = Path(args.json)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(report, indent=2) + "\n")
        print(f"wrote {path}")
    if args.plot:
        from ..benchmark.plots import plot_validity_check

        threshold = report["thresholds"]["min_auroc"]
        print(f"wrote {plot_validity_check(report['scenarios'], Path(args.plot), threshold)}")
    per_seed = ", ".join(f"{n} at seed {s}" for n, s in zip(report["n_pass_per_seed"], seeds, strict=True))
    print(f"{report['n_pass']}/{report['n_scenarios']} scenarios pass at every seed ({per_seed})")
    return 0


REPORT_KEYS = ("scenarios", "summary", "seeds", "n_pass", "n_pass_per_seed", "n_scenarios", "settings", "thresholds")


def load_report(path: Path) -> dict:
    """A report written by `--json`; one from an earlier version of the check is refused by what it lacks."""
    report = json.loads(path.read_text())
    missing = [k for k in REPORT_KEYS if k not in report]
    if missing:
        raise ValueError(f"{path} lacks {missing}: it was written by an earlier kvm-check; measure again")
    return report


def measure(args: argparse.Namespace) -> dict:
    from ..evaluation.validity_check import check_validity_suite

    return check_validity_suite(
        resolve_tasks(args.tasks),
        seeds=args.seeds,
        episodes=args.episodes,
        held_out=args.held_out,
        offline_steps=(args.offline_steps, args.new_skill_steps),
        feedback_steps=args.feedback_steps,
        risk_model=args.risk_model,
    )


def kvm_choice(p: argparse.ArgumentParser, name: str, choices: tuple[str, ...], help_text: str) -> None:
    """`--<name>` for the KVM option `name`: its choices, its default from `KvmConfig`."""
    p.add_argument(
        "--" + name.replace("_", "-"),
        choices=choices,
        default=getattr(KvmConfig, name),
        help=f"{help_text} (policy.kvm.{name})",
    )


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--tasks", default="all", help="scenario ids, categories (A,B,C) or 'all', comma separated")
    p.add_argument("--episodes", type=int, default=8, help="offline expert episodes per skill (prior variant)")
    p.add_argument("--held-out", type=int, default=4, help="held-out seeds per (variant, skill)")
    p.add_argument("--offline-steps", type=int, default=300, help="training steps on the prior skill (core, KVM)")
    p.add_argument("--new-skill-steps", type=int, default=200, help="training steps on the safe skill (core, KVM)")
    p.add_argument(
        "--feedback-steps",
        type=int,
        default=KvmConfig.feedback_steps,
        help="gradient steps of the one feedback (policy.kvm.feedback_steps; the benchmark gives every method 100)",
    )
    kvm_choice(p, "risk_model", RISK_MODELS, "how the KVM scores a (context, skill) pair")
    p.add_argument(
        "--seeds", type=seed_list, default=(0,), help="comma-separated seeds; each scenario is checked at each of them"
    )
    p.add_argument("--json", help="also write the full report to this JSON file")
    p.add_argument("--plot", help="also draw every scenario's AUROC at each seed against the references (PNG)")
    p.add_argument("--from-json", help="tabulate (and --plot) a report written by --json instead of measuring")
    p.set_defaults(func=run)
