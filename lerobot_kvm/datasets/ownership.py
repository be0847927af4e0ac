"""Whether the process that made a lock or a temporary directory still runs: what decides if it may be removed."""

import os


def process_alive(pid: int) -> bool:
    """True while `pid` runs (another user's process counts as running: it is not ours to judge)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True
