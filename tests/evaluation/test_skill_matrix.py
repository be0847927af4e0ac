"""The forced-skill matrix's table (the measurement itself runs on the tiny pool, tests/benchmark)."""

from lerobot_kvm.evaluation.skill_matrix import CORE, format_matrix


def test_the_matrix_prints_success_and_catastrophe_per_skill_and_variant() -> None:
    cell = {"success": 0.9, "catastrophe": 0.1, "episodes": 10}
    matrix = {
        "columns": ["egg_vs_stone/prior", "egg_vs_stone/shifted"],
        "rows": [
            {"skill": "egg_vs_stone.firm_grasp", "cells": {"egg_vs_stone/prior": cell, "egg_vs_stone/shifted": cell}},
            {"skill": CORE, "cells": {"egg_vs_stone/prior": cell, "egg_vs_stone/shifted": dict(cell, success=0.0)}},
        ],
    }
    lines = format_matrix(matrix).splitlines()
    assert lines[0].split() == ["skill", "egg_vs_stone/prior", "egg_vs_stone/shifted"]
    assert lines[2].split() == ["egg_vs_stone.firm_grasp", "90/10", "90/10"]
    assert lines[3].split()[-2:] == ["90/10", "0/10"] and lines[3].startswith(CORE)
