"""lerobot_kvm: CODA-Prompt + Knowledge Validity Module for LeRobot, and its MuJoCo suite.

Importing the package registers the `coda_kvm` policy and the `kvm_obsolescence` env type.
"""

import os

# The suite renders offscreen; MuJoCo picks its GL backend when it is first imported, so the headless default
# is set before that (an explicit MUJOCO_GL always wins).
os.environ.setdefault("MUJOCO_GL", "egl")

from . import envs, policy  # noqa: E402, F401
