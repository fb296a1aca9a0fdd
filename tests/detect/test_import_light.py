"""The detector path runs without torch: spawned detector workers and ``cotrain detect`` start fast
(importing torch takes about a second)."""

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


def test_detecting_does_not_import_torch():
    """Both detectors, through the steps that read the board's print (completion, the print check)."""
    code = (
        "import sys\n"
        "import numpy as np\n"
        "from cotrain.detect.detector import Detector\n"
        "from cotrain.detect.print_model import CompletionConfig, print_patches, smallest_step\n"
        "from cotrain.targets import AprilGrid, Checkerboard\n"
        "image = np.random.default_rng(0).random((240, 320)).astype(np.float32)\n"
        "Detector().detect(image)\n"
        "Detector(target=AprilGrid()).detect(image)\n"
        "for board in (Checkerboard(), AprilGrid()):\n"
        "    print_patches(board, CompletionConfig())\n"
        "    smallest_step(board)\n"
        "assert 'torch' not in sys.modules, 'torch was imported while detecting'\n"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr
