"""The suite tools through the installed `lerobot-kvm` console script, as a user runs them."""

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
from PIL import Image

pytestmark = pytest.mark.slow

LEROBOT_KVM = Path(sys.executable).parent / "lerobot-kvm"


def lerobot_kvm(*args: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}
    result = subprocess.run([str(LEROBOT_KVM), *args], capture_output=True, text=True, env=env, timeout=600)
    assert result.returncode == 0, result.stderr[-3000:]
    return result


def test_check_suite_writes_a_complete_report(tmp_path):
    out = tmp_path / "suite.json"
    result = lerobot_kvm("check-suite", "--tasks", "egg_vs_stone", "--episodes", "2", "--seed", "3", "--json", str(out))
    assert re.search(r"^[01]/1 scenarios pass", result.stdout, re.M), result.stdout
    assert "egg_vs_stone" in result.stdout.splitlines()[2]  # first row of the table, under header and rule

    report = json.loads(out.read_text())
    assert (report["seed"], report["episodes"], report["seeds"]) == (3, 2, [3, 4])
    assert set(report["versions"]) == {"mujoco", "lerobot_kvm"} and report["wall_time_s"] > 0
    assert report["n_scenarios"] == 1 and report["n_pass"] in (0, 1)
    (row,) = report["scenarios"]
    assert (row["id"], row["category"]) == ("egg_vs_stone", "C")
    rates = [k for k in row if k.endswith(("_success", "_catastrophe"))]
    assert {
        "prior_on_prior_success",
        "prior_on_prior_catastrophe",
        "prior_on_shifted_catastrophe",
        "safe_on_shifted_success",
        "safe_on_shifted_catastrophe",
        "control_prior_skill_success",
        "control_prior_skill_catastrophe",
    } <= set(rates)
    for key in rates:
        assert row[key] is None if key.startswith("control") else 0.0 <= row[key] <= 1.0, key
    assert 0.0 < row["reset_image_diff"] <= 255.0  # C: a different object, so the image must differ
    assert row["env_steps_per_s"] > 0
    assert set(row["passes"]) >= {"prior_on_prior", "prior_on_shifted", "safe_on_shifted", "reset_image_diff"}
    assert row["passes"]["control_prior_skill"] is None
    rescue = {"false_alarm", "detected", "detection_step", "harm_step", "last_rescue_step", "rescue_0", "rescue_5"}
    assert rescue <= set(row) and 0.0 <= row["false_alarm"] <= 1.0
    assert row["passes"]["rescue"] is None  # the rescue rule is for hidden shifts (A/B); C only reports it
    assert " r5 " in result.stdout.splitlines()[0] and "rescue" in result.stdout.splitlines()[0]
    assert row["passed"] == all(v for v in row["passes"].values() if v is not None)


def test_catalogue_lists_the_scenario(tmp_path):
    out = tmp_path / "scenarios.md"
    lerobot_kvm("catalogue", "--tasks", "egg_vs_stone", "--out", str(out))
    text = out.read_text()
    rows = [line for line in text.splitlines() if line.startswith("| `")]
    assert len(rows) == 1 and "`egg_vs_stone`" in rows[0]
    assert "pick up the stone" in rows[0] and "pick up the egg" in rows[0] and "`break`" in rows[0]


def test_contact_sheet_has_one_row_of_four_panels(tmp_path):
    out = tmp_path / "sheet.png"
    lerobot_kvm("contact-sheet", "--tasks", "egg_vs_stone", "--size", "96", "--out", str(out))
    image = Image.open(out)
    assert image.width > 4 * 96 and 96 < image.height < 2 * 96 + 100
    assert len(image.convert("L").getcolors(maxcolors=1 << 16)) > 50  # rendered panels, not a blank page
