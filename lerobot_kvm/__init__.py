"""lerobot_kvm: CODA-Prompt + Knowledge Validity Module for LeRobot, and its MuJoCo suite.

Importing the package registers the `coda_kvm` policy and the `kvm_obsolescence` env type.
"""

from . import envs, policy  # noqa: F401
