"""`report.md` of a benchmark run: tables shaped like the paper's (Table 1/9 per category and pass, Table 4
ablations and peers, Table 10 gate statistics, Table 11 overhead), the pool's continual-learning metrics, and
the plots in `plots/`."""

from collections.abc import Sequence
from pathlib import Path
from typing import Any

from ..envs.catalogue import CATEGORIES

# The benchmark's diagnostic rows: told the variant and where the shift shows, so never methods (`protocol.py`).
PRIVILEGED = ("oracle_skill", "oracle_switch")


def _label(name: str) -> str:
    return f"{name} (privileged)" if name in PRIVILEGED else name


def _pct(value: float | None, digits: int = 1) -> str:
    return "-" if value is None else f"{100 * value:.{digits}f}"


def _num(value: float | None, digits: int = 1) -> str:
    return "-" if value is None else f"{value:.{digits}f}"


def _table(header: list[str], rows: list[list[str]]) -> list[str]:
    return [
        "| " + " | ".join(header) + " |",
        "|" + "---|" * len(header),
        *["| " + " | ".join(r) + " |" for r in rows],
        "",
    ]


def category_table(results: dict[str, Any]) -> list[str]:
    """Table 1/9: solved challenges per category and pass, "k/n (%)"."""
    passes = sorted(next(iter(results["methods"].values()))["per_pass"], key=int)
    categories = sorted({c for m in results["methods"].values() for c in m["overall"]["per_category"]})
    header = ["method", *[f"{c} R{p}" for c in categories for p in passes], "overall"]
    rows = []
    for name, res in results["methods"].items():
        cells = [res["per_pass"][p]["per_category"].get(c, "-") for c in categories for p in passes]
        rows.append([_label(name), *cells, res["overall"]["success"]])
    legend = ", ".join(f"{c}: {CATEGORIES[c]}" for c in categories)
    return _table(header, rows) + [f"Categories: {legend}. R1-R3: passes (knowledge kept across passes).", ""]


def scenario_table(results: dict[str, Any]) -> list[str]:
    """Solved challenges and catastrophic attempts per scenario, every pass and run together."""
    met = {s for m in results["methods"].values() for s in m["overall"]["per_scenario"]}
    scenarios = [s for s in results["config"]["scenarios"] if s in met]
    rows = []
    for name, res in results["methods"].items():
        per = res["overall"]["per_scenario"]
        rows.append(
            [_label(name), *(f"{per[s]['solved']} · {per[s]['catastrophes']}" if s in per else "-" for s in scenarios)]
        )
    return _table(["method", *scenarios], rows) + [
        "Cells: challenges solved · attempts ending in a catastrophe. `oracle_skill` bounds a scenario by its safe "
        "skill's own quality, `oracle_switch` by the rescue window a detector of the shift gets; a method below both "
        "falls short in its detection or its switch.",
        "",
    ]


def _with_interval(res: dict[str, Any], key: str) -> str:
    """A rate in percent and, where measured, its 95 % interval: "33.3 [16.1, 50.0]"."""
    interval = res.get("intervals", {}).get(key)
    value = _pct(res["overall"].get(key))
    if interval is None or interval["low"] is None:
        return value
    return f"{value} [{_pct(interval['low'])}, {_pct(interval['high'])}]"


def method_table(results: dict[str, Any]) -> list[str]:
    """Table 4: every method and ablation on the headline metrics, each rate with its 95 % interval."""
    rows = []
    for name, res in results["methods"].items():
        rows.append(
            [
                _label(name),
                *[
                    _with_interval(res, key)
                    for key in (
                        "success_rate",
                        "first_attempt_success_rate",
                        "catastrophic_failure_rate",
                        "abstention_rate",
                    )
                ],
                _with_interval(res, "prior_retention"),
                _with_interval(res, "control_success_rate"),
                _with_interval(res, "false_intervention_rate"),
                _num(res["wall_time_s"] / 60),
            ]
        )
    header = ["method", "success (%)", "1st attempt (%)", "CFR (%)", "abstentions (%)", "prior retention (%)"]
    header.append("benign control (%)")
    return _table([*header, "false interventions (%)", "episodes + feedback (min)"], rows)


def time_lines(breakdown: dict[str, Any] | None) -> list[str]:
    """Where this invocation's time went (pool, the (method, run) units over their workers, overhead), and the
    pool's training time as its stages recorded it (which a reused pool keeps)."""
    if not breakdown:
        return []
    m = {k: v / 60 for k, v in breakdown.items() if k.endswith("_s")}
    recorded = [f"{name} {t:.1f}" for name, t in (breakdown.get("pool_training_min") or {}).items() if t is not None]
    pool = f" (training as recorded: {', '.join(recorded)} min)" if recorded else ""
    return [
        f"Time: pool {m['pool_s']:.1f} min{pool}; (method, run) units {m['units_s']:.1f} min on "
        f"{breakdown['workers']} worker(s), {m['unit_episodes_and_feedback_s']:.1f} min of unit time of which "
        f"feedback training {m['unit_feedback_s']:.1f}; overhead measurement {m['overhead_s']:.1f} min.",
        "",
    ]


def feedback_lines(results: dict[str, Any]) -> list[str]:
    """Each method's feedback budget as spent: how many feedbacks, the gradient steps each counted, the step sizes."""
    parts = []
    for name, res in results["methods"].items():
        spent = res.get("feedback")
        if spent is None:
            continue
        steps = "/".join(str(n) for n in spent["steps_each"]) or "-"
        rates = ", ".join(f"{k} {v:g}" for k, v in spent.items() if k not in ("feedbacks", "steps_each", "budget"))
        parts.append(f"`{name}` {spent['feedbacks']} x {steps} steps ({rates})")
    if not parts:
        return []
    budget = results["config"]["feedback_steps"]
    return [
        f"Feedback: {budget} gradient steps per failed first attempt, counted over everything a method trains "
        "(a validity method's KVM and new skill together): " + "; ".join(parts) + ".",
        "",
    ]


DIFFERENCE_LABELS = {
    "success_rate": "success",
    "first_attempt_success_rate": "1st attempt",
    "catastrophic_failure_rate": "CFR",
    "abstention_rate": "abstentions",
    "prior_retention": "prior retention",
    "control_success_rate": "benign control",
    "false_intervention_rate": "false interventions",
    "gate_activation_rate_solved": "gate, solved routine",
}


def difference_table(results: dict[str, Any]) -> list[str]:
    """Each method minus the reference method, in points, with the paired 95 % interval on the difference."""
    diffs = results.get("differences") or {}
    if not diffs.get("methods"):
        return []
    header = ["method", *(f"{label} (pp)" for label in DIFFERENCE_LABELS.values())]
    rows = []
    for name, by_rate in diffs["methods"].items():
        cells = []
        for key in DIFFERENCE_LABELS:
            d = by_rate.get(key)
            if d is None or d["value"] is None:
                cells.append("-")
            elif d["low"] is None:
                cells.append(f"{100 * d['value']:+.1f}")
            else:
                verdict = "" if d["detectable"] else ", no detectable difference"
                cells.append(f"{100 * d['value']:+.1f} [{100 * d['low']:+.1f}, {100 * d['high']:+.1f}]{verdict}")
        rows.append([_label(name), *cells])
    return [
        f"### Differences from `{diffs['reference']}` (paired 95 % intervals)",
        "",
        *_table(header, rows),
        "Points of the method's rate minus the reference's, both resampled on the same runs and scenarios; "
        '"no detectable difference" where the interval includes 0.',
        "",
    ]


def gate_table(results: dict[str, Any]) -> list[str]:
    """Table 10: gate activation on routine episodes, interventions, validity AUROC, detection lead."""
    rows = []
    for name, res in results["methods"].items():
        o = res["overall"]
        if o["gate_activation_rate"] is None:
            continue
        rows.append(
            [
                name,
                _pct(o["gate_activation_rate"]),
                _pct(o["gate_activation_rate_solved"]),
                _pct(o["intervention_rate"]),
                _pct(o["false_intervention_rate"]),
                _num(o["validity_auroc"], 3),
                _num(o["detection_lead_steps"]),
            ]
        )
    gate = ["gate activation, routine (%)", "gate activation, solved routine (%)"]
    rates = ["intervention rate (%)", "false interventions (%)"]
    return _table(["method", *gate, *rates, "validity AUROC", "detection lead (steps)"], rows)


def overhead_table(overhead: dict[str, Any] | None) -> list[str]:
    """Table 11: per-step latency of the backbone alone and with the KVM (gate closed / open), and memory."""
    if overhead is None:
        return ["No validity method was run: no overhead measured.", ""]
    call, step = overhead["model_call_ms"], overhead["control_step_ms"]
    rows = [
        ["model call (ms)", _num(call["off"], 2), _num(call["closed"], 2), _num(call["open"], 2)],
        ["control step (ms)", _num(step["off"], 2), _num(step["closed"], 2), _num(step["open"], 2)],
        [
            "ratio to KVM off",
            "1.00",
            f"{overhead['ratio_gate_closed']:.3f}",
            f"{overhead['ratio_gate_open']:.3f}",
        ],
    ]
    paired = [  # reports written before the paired ratios have none
        ("paired ratio (per rotation)", "paired_ratio_gate"),
        ("paired ratio, control step", "paired_control_step_ratio_gate"),
    ]
    for label, key in paired:
        if f"{key}_closed" in overhead:
            rows.append([label, "1.00", f"{overhead[f'{key}_closed']:.3f}", f"{overhead[f'{key}_open']:.3f}"])
    lines = _table(["", "KVM off (backbone)", "gate closed", "gate open"], rows)
    lines.append(
        f"KVM state {overhead['kvm_state_mb']:.1f} MiB of the policy's {overhead['policy_state_mb']:.1f} MiB; "
        f"device {overhead.get('device', 'cpu')}, {overhead['threads']} threads, {overhead['calls_per_mode']} calls "
        f"per mode, inputs: {overhead['inputs']}."
    )
    return [*lines, ""]


def pool_table(results: dict[str, Any]) -> list[str]:
    rows = [
        [name, *[_pct(m.get(k), 0) for k in ("A_N", "F_N", "FWT", "NBT", "AUC")]]
        for name, m in results["pool"]["continual_metrics"].items()
    ]
    return _table(["method", "A_N (%)", "F_N (pp)", "FWT (%)", "NBT (pp)", "AUC (%)"], rows)


def coverage_lines(uncovered: list[str]) -> list[str]:
    """A warning when some challenges meet no obsolete knowledge (see `protocol.uncovered_scenarios`)."""
    if not uncovered:
        return []
    return [
        f"**Pool coverage:** the pool never learned the prior skill of {', '.join(uncovered)} under the variant's own "
        "instruction, so those challenges test no obsolete knowledge (and the KVM's context is novel there).",
        "",
    ]


def markdown(results: dict[str, Any], plots: list[Path], account: Sequence[str] = ()) -> str:
    """The report: `account` (what the reference method did in each challenge) comes before the tables."""
    cfg = results["config"]
    lines = [
        f"# Knowledge-obsolescence benchmark `{results['benchmark']}`",
        "",
        f"{len(cfg['scenarios'])} scenarios x {cfg['passes']} passes x {cfg['runs']} runs per method; feedback: the "
        f"failed trace, one corrective demonstration and {cfg['feedback_steps']} gradient steps. "
        f"This invocation's wall time {results['wall_time_s'] / 60:.1f} min (finished runs are reused).",
        "",
        *time_lines(results.get("time_breakdown")),
        *coverage_lines(results["pool"].get("uncovered_scenarios", [])),
        *account,
        "## Success per category and pass (Table 1/9)",
        "",
        *category_table(results),
        "## Methods and ablations (Table 4)",
        "",
        *method_table(results),
        "CFR: share of challenge attempts ending in a catastrophe. Abstentions: attempts where the policy held "
        "because every candidate skill was suppressed, neither success nor catastrophe. Prior retention: "
        "prior-variant controls solved. Brackets: 95 % interval, bootstrap over runs and scenarios "
        "(docs/benchmark.md). Privileged rows are diagnostics, not methods: `oracle_skill` forces the safe skill "
        "on shifted episodes, `oracle_switch` switches to it where the sensed context leaves the prior variant's "
        "envelope.",
        "",
        *feedback_lines(results),
        *difference_table(results),
        "## Challenges per scenario",
        "",
        *scenario_table(results),
        "## Gate and validity statistics (Table 10)",
        "",
        *gate_table(results),
        "Routine: prior-variant controls; solved routine: those that succeeded (a routine episode that goes wrong "
        "leaves the safe experience, where the gate is right to open).",
        "",
        "## Overhead (Table 11)",
        "",
        *overhead_table(results["overhead"]),
        f"## Skill pool: continual learning on sequence `{results['pool']['sequence']}`",
        "",
        *pool_table(results),
    ]
    if plots:
        lines += ["## Plots", ""]
        lines += [f"![{p.stem}](plots/{p.name})" for p in plots]
        lines.append("")
    return "\n".join(lines)


def _attempt_account(record: dict[str, Any]) -> str:
    """One attempt in words: the skill proposed, when validity fell and what took over, the outcome."""
    parts = [f"`{record.get('proposed') or '-'}` proposed"]
    if record.get("first_intervention") is not None:
        took = record.get("took_over")
        after = f"`{took}` took over" if took else "the policy abstained"
        parts.append(f"validity fell at step {record['first_intervention']}, {after}")
    elif record.get("first_abstention") is not None:
        parts.append(f"abstained at step {record['first_abstention']}")
    else:
        parts.append("nothing suppressed")
    return ", ".join(parts) + f" -> {record['outcome']} at step {record['steps']}"


def challenge_account(records: list[dict[str, Any]], plots_dir: Path) -> list[str]:
    """Each first-pass challenge of the reference method's first run, attempt by attempt, with its trace plot
    (drawn here when the report's own selection left it out)."""
    from .plots import REFERENCE_METHOD, plot_uncertainty_trace, trace_filename

    chosen = [
        r
        for r in records
        if (r["method"], r["run"], r["pass"], r["kind"]) == (REFERENCE_METHOD, 0, 1, "challenge")
        and r.get("series") is not None
    ]
    if not chosen:
        return []
    lines = [f"## What `{REFERENCE_METHOD}` did in each challenge (run 1, pass 1)", ""]
    for r in sorted(chosen, key=lambda r: (r["scenario"], r["attempt"])):
        path = plots_dir / trace_filename(r)
        if not path.exists():
            plot_uncertainty_trace(r, path)
        lines.append(f"* {r['scenario']}, attempt {r['attempt']}: {_attempt_account(r)} ([trace](plots/{path.name}))")
    return [*lines, ""]


def write_report(
    results: dict[str, Any], records: list[dict[str, Any]], probes: list[dict[str, Any]], out: Path
) -> Path:
    """Plots into `out/plots/` and the tables into `out/report.md` (the per-challenge account first)."""
    from .plots import write_plots

    success = {name: res["success_by_pass"] for name, res in results["methods"].items()}
    plots = write_plots(records, probes, success, out / "plots", max_traces=results["config"]["trace_plots"])
    path = out / "report.md"
    path.write_text(markdown(results, plots, challenge_account(records, out / "plots")))
    return path
