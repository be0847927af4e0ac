"""The forced-skill matrix's table (the measurement itself runs on the tiny pool, tests/benchmark)."""

from lerobot_kvm.evaluation.skill_matrix import CORE, format_matrix, own_variant, own_variant_summary


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


def test_a_stage_skill_exists_for_its_prior_or_its_shifted_variant() -> None:
    assert own_variant("egg_vs_stone.firm_grasp") == ("egg_vs_stone", "prior")  # the prior skill
    assert own_variant("egg_vs_stone.gentle_grasp") == ("egg_vs_stone", "shifted")  # the safe skill
    assert own_variant("pretrain") is None and own_variant("egg_vs_stone.kvm_gap_0") is None


def test_the_own_variant_summary_reads_each_stage_skill_where_it_belongs() -> None:
    def cell(success: float) -> dict[str, float]:
        return {"success": success, "catastrophe": 0.0, "episodes": 10}

    matrix = {
        "columns": ["egg_vs_stone/prior", "egg_vs_stone/shifted"],
        "rows": [
            {"skill": "pretrain", "cells": {"egg_vs_stone/prior": cell(0.2), "egg_vs_stone/shifted": cell(0.1)}},
            {"skill": "egg_vs_stone.firm_grasp", "cells": {"egg_vs_stone/prior": cell(1.0)}},
            {
                "skill": "egg_vs_stone.gentle_grasp",
                "cells": {"egg_vs_stone/prior": cell(0.3), "egg_vs_stone/shifted": cell(0.8)},
            },
        ],
    }
    summary = own_variant_summary(matrix)
    assert summary["skills"] == {"egg_vs_stone.firm_grasp": 1.0, "egg_vs_stone.gentle_grasp": 0.8}
    assert summary["mean"] == 0.9 and summary["min"] == 0.8
    assert format_matrix(matrix).splitlines()[3].split() == ["egg_vs_stone.firm_grasp", "100/0", "-"]
