"""The forced-skill matrix: each skill of a `coda_kvm` pool run alone on each scenario variant.

A supervisor can only hand control to knowledge that works on its own. Forcing the fused prompt to one skill
(weight 1 on it, 0 on every other) and running episodes of every (scenario, variant) tells which skill solves
what, and how often it causes the catastrophe; the core's own selection (eq. 3 with every v = 1: the relevances
over the candidates, the KVM off) is the reference row. This bounds what any supervisor can reach with the pool:
a safe alternative that fails alone cannot rescue a suppression.

A stage skill is named "<scenario>.<expert skill>" by the sequence, so the variant it exists for is known: a
prior skill's prior variant, a safe skill's shifted one (it learned the strategy on the prior variant, and the
supervisor hands it the shifted one). `own_only` runs such a skill on its own scenario alone, which keeps the
matrix of a large pool affordable; `own_variant_summary` is the skills' quality on their own variants.
"""

from collections.abc import Sequence
from typing import Any

import torch

from ..envs.catalogue import SCENARIO_INFOS, scenario_info
from ..envs.env import KvmObsolescenceEnv
from .rollouts import run_attempt, skill_alone

CORE = "core (KVM off)"


def own_variant(skill: str) -> tuple[str, str] | None:
    """(scenario, variant) a stage skill exists for: its prior skill's prior variant, its safe skill's shifted
    variant; None for a skill named otherwise (the pretraining skill, a skill the KVM began online)."""
    scenario, _, expert = skill.partition(".")
    info = SCENARIO_INFOS.get(scenario)
    if info is None or expert not in (info.prior_skill, info.safe_skill):
        return None
    return scenario, "prior" if expert == info.prior_skill else "shifted"


def skill_matrix(
    policy: Any,
    pre: Any,
    post: Any,
    scenarios: Sequence[str],
    episodes: int,
    seed: int = 0,
    own_only: bool = False,
) -> dict[str, Any]:
    """{"columns": ["scenario/variant", ...], "rows": [{"skill", "cells": {column: {"success", "catastrophe",
    "episodes"}}}]}: one row per skill forced alone, then the core's own selection. With `own_only` a stage skill
    (`own_variant`) has cells on its own scenario's variants only."""
    if episodes < 1:
        raise ValueError(f"episodes must be >= 1, got {episodes}")
    columns = [(s, v) for s in scenarios for v in scenario_info(s).variants]
    forced: list[tuple[str, torch.Tensor | None]] = [
        (skill.name, skill_alone(policy, skill.index)) for skill in policy.skills
    ]
    forced.append((CORE, None))  # the policy is loaded with the KVM off: its own routing
    rows = [{"skill": name, "cells": {}} for name, _ in forced]
    for scenario, variant in columns:
        env = KvmObsolescenceEnv(scenario, variant=variant)
        try:
            for row, (name, weights) in zip(rows, forced, strict=True):
                own = own_variant(name)
                if own_only and own is not None and own[0] != scenario:
                    continue
                outcomes = [
                    run_attempt(policy, env, pre, post, seed=seed + e, skill_weights=weights)["outcome"]
                    for e in range(episodes)
                ]
                row["cells"][f"{scenario}/{variant}"] = {
                    "success": outcomes.count("success") / episodes,
                    "catastrophe": outcomes.count("catastrophe") / episodes,
                    "episodes": episodes,
                }
        finally:
            env.close()
    return {"columns": [f"{s}/{v}" for s, v in columns], "rows": rows, "episodes": episodes, "seed": seed}


def own_variant_summary(matrix: dict[str, Any]) -> dict[str, Any]:
    """Each stage skill's success on its own variant (`own_variant`), with their mean and minimum: what the pool's
    skills are worth to a supervisor. Skills whose own variant was not run are left out."""
    own = {}
    for row in matrix["rows"]:
        target = own_variant(row["skill"])
        cell = row["cells"].get(f"{target[0]}/{target[1]}") if target else None
        if cell is not None:
            own[row["skill"]] = cell["success"]
    values = list(own.values())
    return {
        "skills": own,
        "mean": sum(values) / len(values) if values else None,
        "min": min(values) if values else None,
    }


def format_matrix(matrix: dict[str, Any]) -> str:
    """Rows: skills; columns: scenario/variant; each cell "success/catastrophe" in percent ("-": not run)."""
    header = ["skill", *matrix["columns"]]

    def cell(c: dict[str, Any] | None) -> str:
        return "-" if c is None else f"{100 * c['success']:.0f}/{100 * c['catastrophe']:.0f}"

    lines = [[row["skill"], *(cell(row["cells"].get(col)) for col in matrix["columns"])] for row in matrix["rows"]]
    widths = [max(len(cell) for cell in col) for col in zip(header, *lines, strict=True)]

    def line(cells: list[str]) -> str:
        return "  ".join(
            c.ljust(w) if i == 0 else c.rjust(w) for i, (c, w) in enumerate(zip(cells, widths, strict=True))
        ).rstrip()

    return "\n".join([line(header), line(["-" * w for w in widths]), *map(line, lines)])
