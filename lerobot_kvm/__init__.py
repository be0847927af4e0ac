"""lerobot_kvm: CODA-Prompt + Knowledge Validity Module for LeRobot, and its MuJoCo suite.

Importing the package registers the `kvm_obsolescence` env type.
"""

from . import envs  # noqa: F401
