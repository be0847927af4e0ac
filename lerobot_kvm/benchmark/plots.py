"""PNG figures of benchmark results for the report.

Inputs are the benchmark's JSON-able records:

* episode record: "method", "run", "pass" (1-based), "scenario", "category", "kind" ("challenge", "prior" or
  "control"), "attempt", "outcome" ("success", "failure" or "catastrophe"), "steps", and "series": None for a
  method without the validity module, else equal-length per-control-step lists "sigma2" (may hold NaN), "tau"
  (-inf where no statistics exist yet), "gate" and "intervention" (0/1).
* probe record: "method", "run", "pass", "scenario", and the energies "e_hazard" / "e_safe" (possibly empty).
* `kvm-check` row: "id", "seed", "passed", and the AUROCs "auroc" (the KVM's v), "neighbour_auroc" and
  "neighbour_auroc_history" (the references told the shift steps), each possibly None.

Figures are built with matplotlib's object-oriented `Figure` and saved through the Agg canvas, never through
`pyplot`: importing or calling this module opens no display, touches no global backend, and leaves no figure
registered anywhere, so long benchmark runs do not accumulate figures in memory.
"""

import math
import re
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator
from matplotlib.transforms import blended_transform_factory

OUTCOME_COLORS = {"success": "tab:green", "failure": "tab:orange", "abstention": "tab:blue", "catastrophe": "tab:red"}
REFERENCE_METHOD = "coda_kvm"  # the method whose validity signals the trace and energy figures focus on
DPI = 120


def _save(fig: Figure, path: Path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=DPI, format="png")
    return path


def _gate_spans(gate: list[int]) -> list[tuple[int, int]]:
    """(first, last) step of every run of consecutive gate-open steps."""
    spans = []
    start = None
    for step, value in enumerate(gate):
        if value and start is None:
            start = step
        elif not value and start is not None:
            spans.append((start, step - 1))
            start = None
    if start is not None:
        spans.append((start, len(gate) - 1))
    return spans


def plot_uncertainty_trace(record: dict, path: Path) -> Path:
    """Plot one episode's sigma_c^2 against the adaptive threshold tau, so a reader sees when and why the gate opened.

    Gate-open steps are shaded, intervention steps are marked in red, and a vertical line gives the episode's end and
    outcome. The y axis is logarithmic when the plotted values span more than two decades.
    """
    series = record.get("series")
    if series is None:
        raise ValueError(
            f"episode record of method {record.get('method')!r} on {record.get('scenario')!r} has no series "
            "(the method runs without the validity module); there is no uncertainty trace to plot"
        )
    sigma2 = np.asarray(series["sigma2"], dtype=float)
    tau = np.asarray(series["tau"], dtype=float)
    gate = [int(v) for v in series["gate"]]
    intervention = np.asarray(series["intervention"], dtype=bool)
    lengths = {"sigma2": len(sigma2), "tau": len(tau), "gate": len(gate), "intervention": len(intervention)}
    if len(set(lengths.values())) > 1:
        raise ValueError(f"the series lists must have equal lengths, got {lengths}")
    steps = np.arange(len(sigma2))

    fig = Figure(figsize=(9, 4), layout="constrained")
    ax = fig.add_subplot()
    for i, (first, last) in enumerate(_gate_spans(gate)):
        label = "gate open" if i == 0 else None  # one legend entry for all spans
        ax.axvspan(first - 0.5, last + 0.5, color="tab:orange", alpha=0.2, linewidth=0, label=label)
    ax.plot(steps, sigma2, color="tab:blue", linewidth=1.2, label=r"$\sigma_c^2$")
    tau_finite = np.where(np.isfinite(tau), tau, np.nan)  # NaN breaks the line where tau is undefined
    if np.isfinite(tau_finite).any():
        ax.plot(steps, tau_finite, color="black", linestyle="--", linewidth=1.0, label=r"threshold $\tau$")

    on_line = intervention & np.isfinite(sigma2)
    if on_line.any():
        ax.plot(steps[on_line], sigma2[on_line], "o", color="red", markersize=4, label="intervention")
    off_line = intervention & ~np.isfinite(sigma2)
    if off_line.any():  # no sigma to sit on: mark at the bottom edge instead
        bottom = blended_transform_factory(ax.transData, ax.transAxes)
        ax.plot(
            steps[off_line],
            np.zeros(off_line.sum()),
            "^",
            color="red",
            markersize=5,
            transform=bottom,
            label=r"intervention ($\sigma_c^2$ undefined)",
        )

    outcome = record["outcome"]
    color = OUTCOME_COLORS.get(outcome, "gray")
    end = record["steps"]
    ax.axvline(end, color=color, linewidth=1.5, label=f"end: {outcome}")
    top = blended_transform_factory(ax.transData, ax.transAxes)
    ax.text(end, 0.98, f"{outcome} ", transform=top, color=color, ha="right", va="top", fontweight="bold")

    plotted = np.concatenate([sigma2, tau_finite])
    plotted = plotted[np.isfinite(plotted)]
    if plotted.size and plotted.min() > 0 and plotted.max() / plotted.min() > 100:
        ax.set_yscale("log")
    ax.set_xlim(-0.5, max(end, len(steps) - 1) + 1)
    ax.set_xlabel("control step")
    ax.set_ylabel(r"$\sigma_c^2$")
    ax.set_title(
        f"{record['scenario']} ({record['kind']}, attempt {record['attempt']}, pass {record['pass']}) — "
        f"{record['method']}"
    )
    ax.legend(loc="upper left", fontsize="small")
    return _save(fig, path)


def _pool(probes: list[dict], key: str) -> np.ndarray:
    values = np.asarray([v for probe in probes for v in probe[key]], dtype=float)
    return values[np.isfinite(values)]


def plot_energy_histograms(probes: list[dict], path: Path) -> Path:
    """Overlay the pooled safe and hazardous energies, to show how well the energy separates the two."""
    safe = _pool(probes, "e_safe")
    hazard = _pool(probes, "e_hazard")
    fig = Figure(figsize=(7, 4), layout="constrained")
    ax = fig.add_subplot()
    ax.set_xlabel("energy")
    ax.set_ylabel("count")
    ax.set_title(f"Probe energies, pooled over {len(probes)} probe(s)")
    pooled = np.concatenate([safe, hazard])
    if pooled.size == 0:
        ax.text(0.5, 0.5, "no energies recorded", transform=ax.transAxes, ha="center", va="center")
        return _save(fig, path)
    low, high = float(pooled.min()), float(pooled.max())
    if low == high:
        low, high = low - 0.5, high + 0.5
    bins = np.linspace(low, high, 41)  # shared bins so the two histograms compare bar for bar
    ax.hist(safe, bins=bins, alpha=0.5, color="tab:blue", label=f"safe (n={safe.size})")
    ax.hist(hazard, bins=bins, alpha=0.5, color="tab:red", label=f"hazardous (n={hazard.size})")
    ax.yaxis.set_major_locator(MaxNLocator(integer=True))
    ax.legend()
    return _save(fig, path)


def plot_success_by_pass(success: dict[str, dict[int, float]], path: Path) -> Path:
    """Grouped bars of each method's success rate per pass, to compare how methods adapt over passes R1, R2, ...

    `success[method][pass]` is a rate in [0, 1]; it is drawn in percent. A pass a method lacks gets no bar.
    """
    for method, by_pass in success.items():
        for pass_, rate in by_pass.items():
            if not 0.0 <= rate <= 1.0:
                raise ValueError(f"success rate of {method!r} in pass {pass_} must be in [0, 1], got {rate!r}")
    methods = list(success)
    passes = sorted({pass_ for by_pass in success.values() for pass_ in by_pass})
    fig = Figure(figsize=(max(6, 1.5 * len(passes) * max(len(methods), 1)), 4), layout="constrained")
    ax = fig.add_subplot()
    ax.set_ylim(0, 105)
    ax.set_ylabel("success (%)")
    ax.set_title("Success rate by pass")
    if not passes:
        ax.text(0.5, 0.5, "no success rates recorded", transform=ax.transAxes, ha="center", va="center")
        return _save(fig, path)
    width = 0.8 / len(methods)
    centers = np.arange(len(passes))
    for i, method in enumerate(methods):
        heights = [100.0 * success[method].get(p, math.nan) for p in passes]
        bars = ax.bar(centers + (i - (len(methods) - 1) / 2) * width, heights, width, label=method)
        labels = ["" if math.isnan(h) else f"{h:.0f}%" for h in heights]
        ax.bar_label(bars, labels=labels, fontsize="small", padding=2)
    ax.set_xticks(centers, [f"R{p}" for p in passes])
    ax.set_xlabel("pass")
    ax.legend(fontsize="small")
    return _save(fig, path)


VALIDITY_MARKERS = (  # (row key, label, marker, filled): the KVM's AUROC and the references it is read against
    ("auroc", "KVM validity v", "o", True),
    ("neighbour_auroc", "reference told the shift: sensed context", "s", False),
    ("neighbour_auroc_history", "reference told the shift: sensed context + history", "^", False),
)


def plot_validity_check(rows: list[dict], path: Path, threshold: float = 0.95) -> Path:
    """One line per scenario: the KVM's AUROC at each seed against the nearest-neighbour references that are told
    the shift steps, and the acceptance threshold, so a reader sees which scenarios miss and whether their sensed
    context carries the shift at all. Scenarios are sorted by the KVM's lowest AUROC; red names fail at a seed."""
    if not rows:
        raise ValueError("no kvm-check rows to plot")
    ids = sorted({r["id"] for r in rows}, key=lambda i: min(r.get("auroc") or 0.0 for r in rows if r["id"] == i))
    seeds = sorted({r["seed"] for r in rows})
    fig = Figure(figsize=(8, 1.2 + 0.32 * len(ids)), layout="constrained")
    ax = fig.add_subplot()
    offsets = {key: (j - 1) * 0.22 for j, (key, *_) in enumerate(VALIDITY_MARKERS)}
    for key, label, marker, filled in VALIDITY_MARKERS:
        xs, ys = [], []
        for y, scenario in enumerate(ids):
            for r in rows:
                if r["id"] == scenario and r.get(key) is not None:
                    xs.append(r[key])
                    ys.append(y + offsets[key])
        face = "tab:blue" if filled else "none"
        ax.scatter(xs, ys, marker=marker, facecolors=face, edgecolors="tab:blue" if filled else "0.35", label=label)
    ax.axvline(threshold, color="tab:red", linestyle="--", linewidth=1, label=f"threshold {threshold}")
    ax.set_yticks(range(len(ids)), ids)
    for tick, scenario in zip(ax.get_yticklabels(), ids, strict=True):
        if not all(r["passed"] for r in rows if r["id"] == scenario):
            tick.set_color("tab:red")
    ax.invert_yaxis()
    ax.set_xlabel("AUROC: hazardous vs safe (skill, context) pairs")
    title = f"kvm-check: {len(ids)} scenarios, seeds {', '.join(map(str, seeds))}"
    ax.set_title(title)
    ax.grid(axis="x", alpha=0.3)
    ax.legend(fontsize="small", loc="best")
    return _save(fig, path)


def _safe_name(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "-", str(text))


def trace_filename(record: dict) -> str:
    """File name of an episode's trace plot (the run is not part of it: one trace per method/scenario/pass/attempt)."""
    return (
        f"trace_{_safe_name(record['method'])}_{_safe_name(record['scenario'])}"
        f"_p{record['pass']}_a{record['attempt']}.png"
    )


def _trace_priority(record: dict) -> tuple:
    """Sort key: first the reference method's first challenge attempts where the gate opened, then the rest."""
    featured = (
        record["method"] == REFERENCE_METHOD
        and record["kind"] == "challenge"
        and record["attempt"] == 1
        and any(record["series"]["gate"])
    )
    return (
        not featured,
        str(record["method"]),
        str(record["scenario"]),
        record["pass"],
        record["attempt"],
        record["run"],
    )


def write_plots(
    records: list[dict],
    probes: list[dict],
    success: dict[str, dict[int, float]],
    out_dir: Path,
    max_traces: int = 6,
) -> list[Path]:
    """Write the report's figures into `out_dir` and return their paths.

    Writes `success_by_pass.png`, `energy_histograms.png` (the reference method's probes when it has any, else all
    probes) and up to `max_traces` uncertainty traces chosen deterministically by `_trace_priority`; when several
    runs share a trace file name, the first in that order is kept.
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = [plot_success_by_pass(success, out_dir / "success_by_pass.png")]
    reference_probes = [probe for probe in probes if probe["method"] == REFERENCE_METHOD]
    paths.append(plot_energy_histograms(reference_probes or probes, out_dir / "energy_histograms.png"))
    chosen: dict[str, dict] = {}
    for record in sorted((r for r in records if r.get("series") is not None), key=_trace_priority):
        if len(chosen) >= max_traces:
            break
        chosen.setdefault(trace_filename(record), record)
    paths.extend(plot_uncertainty_trace(record, out_dir / name) for name, record in chosen.items())
    return paths
