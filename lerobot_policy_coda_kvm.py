"""Entry point LeRobot imports by distribution name; importing it registers `coda_kvm` and `kvm_obsolescence`."""

import lerobot_kvm.envs  # noqa: F401
import lerobot_kvm.policy  # noqa: F401
