"""The forced-skill matrix: each skill of a `coda_kvm` pool run alone on each scenario variant.

A supervisor can only hand control to knowledge that works on its own. Forcing the fused prompt to one skill
(weight 1 on it, 0 on every other) and running episodes of every (scenario, variant) tells which skill solves
what, and how often it causes the catastrophe; the core's own selection (eq. 3 with every v = 1: the relevances
over the candidates, the KVM off) is the reference row. This bounds what any supervisor can reach with the pool:
a safe alternative that fails alone cannot rescue a suppression.
"""

from collections.abc import Sequence
from typing import Any

import torch

from ..envs.catalogue import scenario_info
from ..envs.env import KvmObsolescenceEnv
from .rollouts import run_attempt

CORE = "core (KVM off)"


def skill_matrix(
    policy: Any, pre: Any, post: Any, scenarios: Sequence[str], episodes: int, seed: int = 0
) -> dict[str, Any]:
    """{"columns": ["scenario/variant", ...], "rows": [{"skill", "cells": {column: {"success", "catastrophe",
    "episodes"}}}]}: one row per skill forced alone, then the core's own selection."""
    if episodes < 1:
        raise ValueError(f"episodes must be >= 1, got {episodes}")
    columns = [(s, v) for s in scenarios for v in scenario_info(s).variants]
    n = policy.n_skills
    device = policy.config.device
    forced: list[tuple[str, torch.Tensor | None]] = [  # one-hot: the skill's own prompt
        (skill.name, torch.nn.functional.one_hot(torch.tensor([skill.index]), n).float().to(device))
        for skill in policy.skills
    ]
    forced.append((CORE, None))  # the policy is loaded with the KVM off: its own routing
    rows = [{"skill": name, "cells": {}} for name, _ in forced]
    for scenario, variant in columns:
        env = KvmObsolescenceEnv(scenario, variant=variant)
        try:
            for row, (_, weights) in zip(rows, forced, strict=True):
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


def format_matrix(matrix: dict[str, Any]) -> str:
    """Rows: skills; columns: scenario/variant; each cell "success/catastrophe" in percent."""
    header = ["skill", *matrix["columns"]]
    lines = [
        [row["skill"], *(f"{100 * c['success']:.0f}/{100 * c['catastrophe']:.0f}" for c in row["cells"].values())]
        for row in matrix["rows"]
    ]
    widths = [max(len(cell) for cell in col) for col in zip(header, *lines, strict=True)]

    def line(cells: list[str]) -> str:
        return "  ".join(
            c.ljust(w) if i == 0 else c.rjust(w) for i, (c, w) in enumerate(zip(cells, widths, strict=True))
        ).rstrip()

    return "\n".join([line(header), line(["-" * w for w in widths]), *map(line, lines)])
