"""A dataset root checked before a run hands it to LeRobot, so that a fault names the file, not a traceback.

LeRobot reads an empty or missing root as a hub repository to download (offline: "Cannot reach
huggingface.co"), and a truncated `meta/info.json` or a corrupt parquet file as a long traceback from deep inside.
"""

from pathlib import Path

import pyarrow.parquet as pq

from .json_config import read_json

INFO = "meta/info.json"


def check_dataset(root: str | Path, required: tuple[str, ...] = ("action", "observation.state")) -> dict:
    """The dataset's `meta/info.json`, after checking the root, that file, every parquet file and `required`
    features; a ValueError names the first fault found."""
    root = Path(root)
    if not root.is_dir():
        raise ValueError(f"dataset root {root} does not exist or is not a directory")
    if not any(root.iterdir()):
        raise ValueError(f"dataset root {root} is empty")
    info_path = root / INFO
    try:
        info = read_json(info_path)
    except FileNotFoundError:
        raise ValueError(f"{info_path} is missing: {root} is not a LeRobot dataset") from None
    features = info.get("features")
    if not isinstance(features, dict):
        raise ValueError(f"{info_path} has no 'features' table")
    missing = [name for name in required if name not in features]
    if missing:
        raise ValueError(f"{root} lacks the features {missing}; it has {sorted(features)}")
    files = sorted((root / "data").rglob("*.parquet"))
    if not files:
        raise ValueError(f"{root / 'data'} holds no parquet file: the dataset has no frames")
    for path in [*files, *sorted((root / "meta").rglob("*.parquet"))]:
        try:
            pq.read_metadata(path)
        except Exception as err:  # pyarrow raises several kinds for a damaged file
            raise ValueError(f"{path} is not a readable parquet file ({err})") from None
    return info
