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


def _flat(value: Any, path: str = "") -> dict[str, Any]:
    """Nested settings by path ('recording.items[0].episodes'), so that a difference names the setting itself.
    A list of plain values stays whole (`scenarios`)."""
    if isinstance(value, dict):
        items = [(f"{path}.{k}" if path else str(k), v) for k, v in value.items()]
    elif isinstance(value, list) and any(isinstance(v, dict | list) for v in value):
        items = [(f"{path}[{i}]", v) for i, v in enumerate(value)]
    else:
        return {path: value}
    return {k: v for key, item in items for k, v in _flat(item, key).items()}


def _as_read_back(settings: dict[str, Any]) -> dict[str, Any]:
    """Settings as JSON reads them back (tuples become lists), so that fresh ones compare with recorded ones."""
    return json.loads(json.dumps(settings))


def differences(kept: dict[str, Any], current: dict[str, Any]) -> str:
    """'setting: old -> new; ...' for every setting that differs, nested ones by path ('' when none does)."""
    kept, current = _flat(_as_read_back(kept)), _flat(_as_read_back(current))
    keys = sorted(kept.keys() | current.keys())
    pairs = [(k, kept.get(k, _ABSENT), current.get(k, _ABSENT)) for k in keys]
    return "; ".join(f"{k}: {_describe(old)} -> {_describe(new)}" for k, old, new in pairs if old != new)


def check_settings(
    directory: Path, settings: dict[str, Any], what: str, remedy: str = "give another output directory"
) -> None:
    """Record `settings` (JSON-able) in `directory` on the first call; afterwards refuse different ones, naming
    each changed setting. `what` says what the directory holds, `remedy` how to start afresh, for the error."""
    path = Path(directory) / SETTINGS
    if not path.exists():
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(settings, indent=2))
        return
    changed = differences(json.loads(path.read_text()), settings)
    if changed:
        raise ValueError(
            f"{directory} holds {what} made with other settings ({changed}). Resume it with the settings it was "
            f"made with, or {remedy}."
        )
