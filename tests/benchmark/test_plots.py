"""Report figures written from small synthetic episode and probe records."""

import math
import sys

import pytest

from lerobot_kvm.benchmark.plots import (
    plot_energy_histograms,
    plot_success_by_pass,
    plot_uncertainty_trace,
    plot_validity_check,
    trace_filename,
    write_plots,
)

PNG_MAGIC = b"\x89PNG"


def _series(n: int, gate_from: int | None, scale: float = 1.0) -> dict:
    sigma2 = [scale * (1.0 + 0.5 * i) for i in range(n)]
    sigma2[1] = math.nan
    tau = [-math.inf, -math.inf] + [scale * 3.0] * (n - 2)
    gate = [int(gate_from is not None and i >= gate_from) for i in range(n)]
    intervention = [int(g and i % 2 == 0) for i, g in enumerate(gate)]
    intervention[1] = 1  # an intervention where sigma is NaN
    return {"sigma2": sigma2, "tau": tau, "gate": gate, "intervention": intervention}


def _record(method: str, scenario: str, *, pass_: int = 1, attempt: int = 1, kind: str = "challenge", **kw) -> dict:
    n = kw.pop("n", 12)
    series = kw.pop("series", _series(n, kw.pop("gate_from", None)))
    return {
        "method": method,
        "run": kw.pop("run", 0),
        "pass": pass_,
        "scenario": scenario,
        "category": "A",
        "kind": kind,
        "attempt": attempt,
        "outcome": kw.pop("outcome", "success"),
        "steps": n,
        "series": series,
    }


def _probe(method: str, e_hazard: list[float], e_safe: list[float]) -> dict:
    return {
        "method": method,
        "run": 0,
        "pass": 1,
        "scenario": "push_block",
        "e_hazard": e_hazard,
        "e_safe": e_safe,
        "v_hazard": [],
        "v_safe": [],
    }


def _assert_png(path) -> None:
    assert path.exists()
    data = path.read_bytes()
    assert data.startswith(PNG_MAGIC) and len(data) > 1000


def test_no_pyplot_figures_left_open(tmp_path):
    plot_uncertainty_trace(_record("coda_kvm", "push_block", gate_from=4), tmp_path / "t.png")
    plot_energy_histograms([_probe("coda_kvm", [2.0, 3.0], [0.5])], tmp_path / "e.png")
    plot_success_by_pass({"act": {1: 0.5}}, tmp_path / "s.png")
    pyplot = sys.modules.get("matplotlib.pyplot")
    assert pyplot is None or pyplot.get_fignums() == []


@pytest.mark.parametrize("outcome", ["success", "failure", "catastrophe"])
def test_uncertainty_trace_writes_png(tmp_path, outcome):
    record = _record("coda_kvm", "push_block", gate_from=5, outcome=outcome)
    path = plot_uncertainty_trace(record, tmp_path / "trace.png")
    assert path == tmp_path / "trace.png"
    _assert_png(path)


def test_uncertainty_trace_log_scale_and_no_tau(tmp_path):
    series = _series(20, gate_from=None, scale=1.0)
    series["sigma2"] = [10.0**i for i in range(-3, 17)]  # spans many decades
    series["tau"] = [-math.inf] * 20  # no statistics at all
    record = _record("coda_kvm", "lift_cube", series=series, n=20, kind="prior", attempt=2, outcome="failure")
    _assert_png(plot_uncertainty_trace(record, tmp_path / "nested" / "log.png"))


def test_uncertainty_trace_rejects_record_without_series(tmp_path):
    record = _record("act", "push_block", series=None)
    with pytest.raises(ValueError, match="no series"):
        plot_uncertainty_trace(record, tmp_path / "none.png")
    assert not (tmp_path / "none.png").exists()


def test_uncertainty_trace_rejects_unequal_series(tmp_path):
    series = _series(8, gate_from=2)
    series["tau"] = series["tau"][:-1]
    with pytest.raises(ValueError, match="equal lengths"):
        plot_uncertainty_trace(_record("coda_kvm", "push_block", series=series, n=8), tmp_path / "bad.png")


def test_energy_histograms(tmp_path):
    probes = [
        _probe("coda_kvm", [3.0, 4.0, 5.5], [0.1, 0.4]),
        _probe("coda_kvm", [4.2], [0.2, math.nan, 0.3]),
        _probe("coda_kvm", [], []),
    ]
    _assert_png(plot_energy_histograms(probes, tmp_path / "energies.png"))


def test_energy_histograms_one_pool_and_constant_values(tmp_path):
    _assert_png(plot_energy_histograms([_probe("coda_kvm", [2.0, 2.0], [])], tmp_path / "one.png"))


def test_energy_histograms_empty(tmp_path):
    _assert_png(plot_energy_histograms([_probe("coda_kvm", [], [])], tmp_path / "empty.png"))
    _assert_png(plot_energy_histograms([], tmp_path / "no_probes.png"))


def test_success_by_pass(tmp_path):
    success = {"coda_kvm": {1: 0.4, 2: 0.75, 3: 0.9}, "act": {1: 0.5, 2: 0.2}}  # act lacks pass 3
    _assert_png(plot_success_by_pass(success, tmp_path / "success.png"))
    _assert_png(plot_success_by_pass({}, tmp_path / "none.png"))


def test_success_by_pass_rejects_percentages(tmp_path):
    with pytest.raises(ValueError, match=r"in \[0, 1\]"):
        plot_success_by_pass({"act": {1: 75.0}}, tmp_path / "bad.png")


def test_write_plots(tmp_path):
    featured = _record("coda_kvm", "push_block", pass_=2, gate_from=3)
    records = [
        _record("act", "aaa_first_alphabetically", series=None),  # no series: never traced
        _record("act_kvm", "aaa_first_alphabetically"),
        _record("coda_kvm", "aaa_first_alphabetically", kind="control", gate_from=2),
        _record("coda_kvm", "aaa_first_alphabetically", attempt=2, gate_from=2),
        _record("coda_kvm", "lift_cube"),  # challenge attempt 1 without gate opening
        _record("coda_kvm", "push_block", pass_=2, gate_from=6, run=1),  # same file name as `featured`
        featured,
        _record("coda_kvm", "stack", pass_=3, gate_from=1),
    ]
    probes = [_probe("act_kvm", [100.0], [100.0]), _probe("coda_kvm", [3.0], [1.0])]
    success = {"coda_kvm": {1: 0.5, 2: 0.8}, "act": {1: 0.5, 2: 0.3}}
    out_dir = tmp_path / "plots"

    paths = write_plots(records, probes, success, out_dir, max_traces=3)

    names = [p.name for p in paths]
    assert names[:2] == ["success_by_pass.png", "energy_histograms.png"]
    traces = names[2:]
    assert traces == [
        "trace_coda_kvm_push_block_p2_a1.png",
        "trace_coda_kvm_stack_p3_a1.png",
        "trace_act_kvm_aaa_first_alphabetically_p1_a1.png",
    ]
    assert trace_filename(featured) in traces
    assert sorted(p.name for p in out_dir.iterdir()) == sorted(names)
    for path in paths:
        assert path.parent == out_dir
        _assert_png(path)


def test_write_plots_is_deterministic_and_respects_max_traces(tmp_path):
    records = [_record("coda_kvm", f"scenario_{i}", gate_from=i % 3 or None) for i in range(5)]
    first = write_plots(records, [], {}, tmp_path / "a", max_traces=2)
    second = write_plots(list(reversed(records)), [], {}, tmp_path / "b", max_traces=2)
    assert [p.name for p in first] == [p.name for p in second]
    assert len(first) == 4
    assert len(write_plots(records, [], {}, tmp_path / "c", max_traces=0)) == 2
    assert len(write_plots(records, [], {}, tmp_path / "d", max_traces=10)) == 2 + 5


def test_validity_check_plot_draws_every_scenario_with_missing_references(tmp_path):
    rows = [
        {"id": "drawer", "seed": 0, "passed": True, "auroc": 0.99, "neighbour_auroc": 0.98},
        {"id": "drawer", "seed": 1, "passed": False, "auroc": 0.93, "neighbour_auroc": None},
        {"id": "pizza", "seed": 0, "passed": True, "auroc": None, "neighbour_auroc_history": 0.97},
    ]
    path = plot_validity_check(rows, tmp_path / "check.png")
    assert path.read_bytes().startswith(PNG_MAGIC)
    with pytest.raises(ValueError, match="no kvm-check rows"):
        plot_validity_check([], tmp_path / "none.png")


def test_the_challenge_account_says_what_the_reference_method_did_and_links_every_trace(tmp_path):
    from lerobot_kvm.benchmark.report import challenge_account

    first = _record("coda_kvm", "potato", outcome="failure", gate_from=4)
    first |= {"proposed": "potato.firm_grasp", "first_intervention": 5, "took_over": "potato.gentle_grasp"}
    second = _record("coda_kvm", "potato", attempt=2, outcome="abstention") | {
        "proposed": "potato.firm_grasp",
        "first_intervention": 3,
        "took_over": None,
    }
    calm = _record("coda_kvm", "drawer") | {"proposed": "drawer.tracking_pull", "first_intervention": None}
    other = [_record("act", "potato"), _record("coda_kvm", "potato", pass_=2), _record("coda_kvm", "potato", run=1)]
    lines = challenge_account([second, first, calm, *other], tmp_path)
    assert lines[2:5] == [
        "* drawer, attempt 1: `drawer.tracking_pull` proposed, nothing suppressed -> success at step 12 "
        "([trace](plots/trace_coda_kvm_drawer_p1_a1.png))",
        "* potato, attempt 1: `potato.firm_grasp` proposed, validity fell at step 5, `potato.gentle_grasp` took over "
        "-> failure at step 12 ([trace](plots/trace_coda_kvm_potato_p1_a1.png))",
        "* potato, attempt 2: `potato.firm_grasp` proposed, validity fell at step 3, the policy abstained "
        "-> abstention at step 12 ([trace](plots/trace_coda_kvm_potato_p1_a2.png))",
    ]
    assert len(lines) == 6 and sorted(p.name for p in tmp_path.iterdir()) == sorted(
        trace_filename(r) for r in (first, second, calm)
    )
