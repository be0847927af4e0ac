"""The recorder's training-only episode labels on disk (`meta/kvm_labels.json`).

Apart from the recorder so that reading them (the policy does, for offline KVM learning) never imports the
simulator.
"""

import json
from pathlib import Path

LABELS_FILE = "meta/kvm_labels.json"


def load_labels(root: str | Path) -> dict:
    """The training-only labels of a recorded dataset: `vocab`, `spec`, `summary`, `episodes`."""
    path = Path(root) / LABELS_FILE
    if not path.exists():
        raise FileNotFoundError(f"{path} missing: {root} was not recorded by lerobot-kvm record")
    return json.loads(path.read_text())


def load_label_vocab(root: str | Path) -> dict[str, list[str]]:
    """The names behind the integer label columns (skill, scenario, variant, outcome)."""
    return load_labels(root)["vocab"]
