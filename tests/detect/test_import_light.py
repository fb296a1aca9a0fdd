"""The detector path imports without torch: spawned detector workers and ``cotrain detect`` start fast."""

import subprocess
import sys


def test_detector_path_does_not_import_torch():
    code = (
        "import sys, cotrain.io.detections, cotrain.cli, cotrain.detect.tag_pass, cotrain.targets.descriptions\n"
        "loaded = 'torch' in sys.modules\n"
        "assert not loaded, 'torch was imported on the detector path'\n"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
