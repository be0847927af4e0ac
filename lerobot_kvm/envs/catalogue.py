"""The scenario catalogue as Markdown, generated from the registry so the docs never drift from the code."""

from .scenario import CATEGORIES, SCENARIOS, ScenarioInfo

HEADER = (
    "| id | cat | instruction per variant | prior skill | safe skill | what changes | catastrophe | "
    "success | control |",
    "|---|---|---|---|---|---|---|---|---|",
)


def _cell(text: str) -> str:
    return text.replace("|", "\\|").replace("\n", " ")


def _row(info: ScenarioInfo) -> str:
    instructions = "<br>".join(f"{v}: “{_cell(info.instructions[v])}”" for v in info.variants)
    cells = [
        f"`{info.id}`<br>{_cell(info.title)}",
        info.category,
        instructions,
        f"`{info.prior_skill}`",
        f"`{info.safe_skill}`",
        _cell(info.what_changes),
        f"`{info.harm}`",
        _cell(info.success),
        "yes" if "control" in info.variants else "no",
    ]
    return "| " + " | ".join(cells) + " |"


def catalogue_markdown(scenario_ids: list[str]) -> str:
    infos = sorted((SCENARIOS[sid].info for sid in scenario_ids), key=lambda i: (i.category, i.id))
    counts = ", ".join(f"{c} ({name}): {sum(i.category == c for i in infos)}" for c, name in CATEGORIES.items())
    lines = [
        "# Scenario catalogue",
        "",
        "Generated from the scenario registry by `lerobot-kvm catalogue --out docs/scenarios.md`; do not edit by hand.",
        "",
        f"{len(infos)} scenarios — {counts}. The prior skill is right on the prior variant and causes the "
        "catastrophe on the shifted one; the safe skill succeeds on the shifted variant. In categories A and B "
        "the shifted variant looks and reads like the prior one; in C it is a similar-looking object with its "
        "own name.",
        "",
        *HEADER,
        *map(_row, infos),
    ]
    return "\n".join(lines) + "\n"
