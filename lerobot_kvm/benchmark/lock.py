"""One run at a time in an output directory.

Two runs in one directory would train into the same checkpoints and interleave their logs. A run holds
`<dir>/.lock` (its pid) while it works; a second run is refused with the holder's pid, and the lock of a run that
was killed (its pid no longer runs) is taken over.
"""

import os
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from ..datasets.ownership import process_alive

LOCK = ".lock"


def _holder(path: Path) -> int | None:
    try:
        text = path.read_text().strip()
    except FileNotFoundError:
        return None
    return int(text) if text.isdigit() else None


@contextmanager
def hold(directory: Path) -> Iterator[None]:
    """Hold `directory` for this process while the block runs (created if absent)."""
    directory.mkdir(parents=True, exist_ok=True)
    path = directory / LOCK
    while True:
        try:
            fd = os.open(path, os.O_CREAT | os.O_EXCL | os.O_WRONLY)
        except FileExistsError:
            holder = _holder(path)
            if holder is not None and holder != os.getpid() and process_alive(holder):
                raise ValueError(
                    f"{directory} is in use by another run (pid {holder}): wait for it or stop it"
                ) from None
            path.unlink(missing_ok=True)  # a killed run's lock (or an unreadable one): taken over
            continue
        with os.fdopen(fd, "w") as f:
            f.write(str(os.getpid()))
        break
    try:
        yield
    finally:
        if _holder(path) == os.getpid():
            path.unlink(missing_ok=True)
