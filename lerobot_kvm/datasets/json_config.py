"""JSON settings files (recording specs, sequence and benchmark configs) read into dataclasses.

Every fault names the file and the key: malformed JSON, a key the dataclass does not have at any depth, a
missing required key, a count below its minimum, a value the dataclass's own checks refuse.
"""

import dataclasses
import json
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any


def read_json(path: str | Path) -> dict[str, Any]:
    """A JSON object from `path`; a missing, unreadable or malformed file is a ValueError naming it."""
    path = Path(path)
    try:
        raw = json.loads(path.read_text())
    except FileNotFoundError:
        raise FileNotFoundError(f"{path}: no such file") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        raise ValueError(f"{path}: not a readable JSON file ({err})") from None
    if not isinstance(raw, dict):
        raise ValueError(f"{path}: expected a JSON object, got {type(raw).__name__}")
    return raw


def build[T](cls: Callable[..., T], raw: Any, where: str) -> T:
    """`cls(**raw)` for a dataclass `cls`; `where` names the object in messages (`file.json: tasks[2]`)."""
    if not isinstance(raw, Mapping):
        raise ValueError(f"{where}: expected an object with keys of {cls.__name__}, got {raw!r}")
    known = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(raw) - known)
    if unknown:
        raise ValueError(f"{where}: unknown keys {unknown}; accepted: {sorted(known)}")
    try:
        return cls(**raw)
    except TypeError as err:  # a required key missing
        raise ValueError(f"{where}: {err}") from None
    except ValueError as err:
        raise ValueError(f"{where}: {err}") from None


def build_list[T](cls: Callable[..., T], raw: dict[str, Any], key: str, where: str) -> list[T]:
    """The list under `raw[key]` (absent: empty), each entry built as `cls`."""
    items = raw.get(key, [])
    if not isinstance(items, list):
        raise ValueError(f"{where}: '{key}' must be a list, got {items!r}")
    return [build(cls, item, f"{where}: {key}[{i}]") for i, item in enumerate(items)]


def check_counts(obj: object, minimums: Mapping[str, int]) -> None:
    """Refuse a count field of `obj` that is not an integer of at least its minimum, naming the field: a zero or
    negative count would otherwise fail late (after settings are written) or be read as a default."""
    for key, least in minimums.items():
        value = getattr(obj, key)
        if isinstance(value, bool) or not isinstance(value, int) or value < least:
            raise ValueError(f"{key} must be >= {least}, got {value!r}")
