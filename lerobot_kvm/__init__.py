"""lerobot_kvm: CODA-Prompt + Knowledge Validity Module for LeRobot, and its MuJoCo suite.

Importing `lerobot_kvm.policy` registers the `coda_kvm` policy type and `lerobot_kvm.envs` the `kvm_obsolescence`
env type; LeRobot's CLIs import both through the plugin module `lerobot_policy_coda_kvm`. The package itself
imports neither, so that a command that needs neither (`lerobot-kvm --help`) starts without torch or LeRobot.
"""

import logging
import os

# The suite renders offscreen; MuJoCo picks its GL backend when it is first imported, so the headless default
# is set before that (an explicit MUJOCO_GL always wins).
os.environ.setdefault("MUJOCO_GL", "egl")

# LeRobot reports, with five tracebacks, that torchcodec's video decoder cannot load without a system FFmpeg. This
# project's datasets hold PNG frames and never decode video, so that one known message is dropped; every other
# record of that logger still shows.
logging.getLogger("lerobot.utils.import_utils").addFilter(
    lambda record: not record.getMessage().startswith("Could not load libtorchcodec")
)
