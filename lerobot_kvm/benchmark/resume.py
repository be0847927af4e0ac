"""Resuming into an output directory only with the settings that made what it holds.

Long runs reuse every finished stage, evaluation and pass they find on disk. Rerun with changed settings, they
would silently mix results of two experiments, so each directory records its settings the first time and later
invocations must bring the same ones.
"""

import json
from pathlib import Path
from typing import Any

SETTINGS = "settings.json"
_ABSENT = object()


def _describe(value: Any) -> str:
    return "(absent)" if value is _ABSENT else json.dumps(value)


def differences(kept: dict[str, Any], current: dict[str, Any]) -> str:
    """'key: old -> new; ...' for every top-level setting that differs ('' when none does)."""
    keys = sorted(kept.keys() | current.keys())
    pairs = [(k, kept.get(k, _ABSENT), current.get(k, _ABSENT)) for k in keys]
    return "; ".join(f"{k}: {_describe(old)} -> {_describe(new)}" for k, old, new in pairs if old != new)


def check_settings(
    directory: Path, settings: dict[str, Any], what: str, remedy: str = "give another output directory"
) -> None:
    """Record `settings` (JSON-able) in `directory` on the first call; afterwards refuse different ones, naming
    each changed setting. `what` says what the directory holds, `remedy` how to start afresh, for the error."""
    path = Path(directory) / SETTINGS
    current = json.loads(json.dumps(settings))  # as it reads back: tuples become lists
    if not path.exists():
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(current, indent=2))
        return
    changed = differences(json.loads(path.read_text()), current)
    if changed:
        raise ValueError(
            f"{directory} holds {what} made with other settings ({changed}). Resume it with the settings it was "
            f"made with, or {remedy}."
        )
