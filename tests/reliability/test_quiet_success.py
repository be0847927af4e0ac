"""Loading a dataset the recorder made prints no traceback (LeRobot's torchcodec notice is not ours to show)."""

import subprocess
import sys

from lerobot_kvm.datasets.recorder import RecordingSpec, RecordItem, record_dataset


def test_loading_a_recorded_dataset_prints_no_traceback(tmp_path):
    root = tmp_path / "data"
    record_dataset(RecordingSpec(name="one", items=[RecordItem("egg_vs_stone", "prior", "firm_grasp", 1)]), root)
    code = (
        "import lerobot_kvm\n"
        "from lerobot.datasets.lerobot_dataset import LeRobotDataset\n"
        f"print(LeRobotDataset('local/one', root={str(root)!r})[0]['action'].shape)\n"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr[-2000:]
    assert "Traceback" not in result.stderr and "libtorchcodec" not in result.stderr, result.stderr[:2000]
