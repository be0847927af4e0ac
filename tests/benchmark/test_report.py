"""The benchmark report's tables from measured values."""

from lerobot_kvm.benchmark.metrics import summarize
from lerobot_kvm.benchmark.report import difference_table, feedback_lines, overhead_table, scenario_table, time_lines

MEASURED = {
    "model_call_ms": {"off": 4.0, "closed": 4.3, "open": 5.0},
    "control_step_ms": {"off": 0.8, "closed": 0.85, "open": 1.0},
    "ratio_gate_closed": 1.075,
    "ratio_gate_open": 1.25,
    "kvm_state_mb": 3.0,
    "policy_state_mb": 40.0,
    "threads": 2,
    "calls_per_mode": 300,
    "inputs": "egg_vs_stone/prior observation",
}


def test_overhead_table_shows_the_paired_ratios_when_measured() -> None:
    without = "\n".join(overhead_table(MEASURED))
    assert "1.075" in without and "paired" not in without  # a report written before the paired ratios
    paired = dict(MEASURED, paired_ratio_gate_closed=1.061, paired_ratio_gate_open=1.238)
    row = next(line for line in overhead_table(paired) if "paired" in line)
    assert "1.061" in row and "1.238" in row
    assert sum("paired" in line for line in overhead_table(paired)) == 1  # no control-step pairs measured
    both = dict(paired, paired_control_step_ratio_gate_closed=1.012, paired_control_step_ratio_gate_open=1.047)
    row = next(line for line in overhead_table(both) if "control step" in line and "paired" in line)
    assert "1.012" in row and "1.047" in row


def test_difference_table_says_where_no_difference_is_detectable() -> None:
    results = {
        "differences": {
            "reference": "coda_kvm",
            "methods": {
                "coda_prompt": {
                    "success_rate": {"value": -0.2, "low": -0.35, "high": -0.05, "detectable": True},
                    "catastrophic_failure_rate": {"value": 0.05, "low": -0.1, "high": 0.2, "detectable": False},
                }
            },
        }
    }
    text = "\n".join(difference_table(results))
    assert "Differences from `coda_kvm`" in text
    row = next(line for line in text.splitlines() if line.startswith("| coda_prompt"))
    cells = [c.strip() for c in row.strip("|").split("|")]
    assert cells[1] == "-20.0 [-35.0, -5.0]"
    assert cells[3] == "+5.0 [-10.0, +20.0], no detectable difference"
    assert cells[2] == "-"  # a rate not measured for this pair
    assert difference_table({"differences": {"reference": None, "methods": {}}}) == []


def test_feedback_lines_state_each_methods_budget_and_step_sizes() -> None:
    results = {
        "config": {"feedback_steps": 100},
        "methods": {
            "coda_kvm": {"feedback": {"feedbacks": 3, "steps_each": [100], "budget": 100, "kvm_lr": 1e-3}},
            "act": {"feedback": {"feedbacks": 2, "steps_each": [100], "budget": 100, "lr": 1e-4, "batch": 16}},
        },
    }
    line = feedback_lines(results)[0]
    assert line.startswith("Feedback: 100 gradient steps per failed first attempt")
    assert "`coda_kvm` 3 x 100 steps (kvm_lr 0.001)" in line and "`act` 2 x 100 steps (lr 0.0001, batch 16)" in line


def test_the_time_line_keeps_the_pool_training_a_reused_pool_recorded() -> None:
    breakdown = {
        "pool_s": 6.0,
        "units_s": 600.0,
        "overhead_s": 60.0,
        "workers": 2,
        "unit_episodes_and_feedback_s": 1200.0,
        "unit_feedback_s": 900.0,
        "pool_training_min": {"coda_kvm": 48.04, "act_joint": None},
    }
    line = time_lines(breakdown)[0]
    assert line.startswith("Time: pool 0.1 min (training as recorded: coda_kvm 48.0 min); (method, run) units 10.0")
    assert "on 2 worker(s), 20.0 min of unit time of which feedback training 15.0" in line
    del breakdown["pool_training_min"]  # results written before the pool's training was kept
    assert time_lines(breakdown)[0].startswith("Time: pool 0.1 min; (method, run)")


def test_the_scenario_table_shows_where_a_method_falls_short_of_the_privileged_rows() -> None:
    def challenge(method: str, scenario: str, *outcomes: str) -> list[dict]:
        return [
            {
                "method": method,
                "run": 0,
                "pass": 1,
                "scenario": scenario,
                "category": "B",
                "kind": "challenge",
                "attempt": k + 1,
                "outcome": o,
                "steps": 10,
                "gate_steps": 0,
                "intervention_steps": 0,
            }
            for k, o in enumerate(outcomes)
        ]

    runs = {
        "coda_kvm": challenge("coda_kvm", "drawer", "abstention", "catastrophe")
        + challenge("coda_kvm", "egg", "success"),
        "oracle_switch": challenge("oracle_switch", "drawer", "success") + challenge("oracle_switch", "egg", "success"),
    }
    results = {
        "config": {"scenarios": ["potato", "drawer", "egg"]},
        "methods": {m: {"overall": summarize(r, validity=False)} for m, r in runs.items()},
    }
    lines = scenario_table(results)
    assert lines[0] == "| method | drawer | egg |"  # the config's order, scenarios never met left out
    assert lines[2] == "| coda_kvm | 0/1 · 1/2 | 1/1 · 0/1 |"
    assert lines[3] == "| oracle_switch (privileged) | 1/1 · 0/1 | 1/1 · 0/1 |"
