"""keep_image_buffers: image-sized buffers are reused from one image to the next (glibc)."""

import subprocess
import sys

import pytest

PROBE = """
import resource, numpy as np
from cotrain.detect.buffers import keep_image_buffers
took = keep_image_buffers()
for _ in range(2):  # the heap grows once
    a, b = np.ones((720, 1280), np.float32), np.ones((720, 1280), np.float32)
    del a, b
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
for _ in range(20):  # two 3.7 MB images' worth of buffers, made, written and freed 20 times
    a, b = np.ones((720, 1280), np.float32), np.ones((720, 1280), np.float32)
    del a, b
print(took, resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's malloc")
def test_freed_image_buffers_are_reused_without_page_faults():
    out = subprocess.run([sys.executable, "-c", PROBE], capture_output=True, text=True, check=True).stdout.split()
    took, faults = out[0] == "True", int(out[1])
    if not took:
        pytest.skip("not glibc: keep_image_buffers does nothing here")
    pages = 720 * 1280 * 4 // 4096  # one buffer's pages (900); fresh mappings each time would fault 36,000
    assert faults < pages, f"{faults} page faults for 40 buffers of {pages} pages"
