"""Image-sized buffers stay with the process from one image to the next.

glibc's malloc gives a freed block of more than its trim threshold (128 KiB at first, raised by
each large block freed, up to 32 MiB for the mmap threshold) back to the system, and the next
image's buffers are then page-faulted in afresh: a 1280x720 float32 image is 3.7 MB (900 pages),
and the tag pass makes a few dozen such buffers per image (blurs, the saddle response, masks).
On this project's 2-core machine one page fault costs about 2 us: the saddle response of one
image took 16-20 ms with fresh buffers and 4-5 ms with reused ones (the same arithmetic), and the
tag pass 104.5 against 96.5 ms per frame over 100 evaluation frames (medians of alternating runs,
docs/benchmarks.md).

:func:`keep_image_buffers` makes glibc keep such blocks for reuse. It is called where many images
are detected in one process (:func:`cotrain.io.detections.detect_files` and its worker processes;
the detection evaluations and ``bench_detect``, so that they time what ``cotrain detect`` runs),
not at import: it is the process's allocator setting, up to ``trim_mb`` of freed memory held.
Elsewhere than glibc (macOS, Windows, musl) it does nothing.
"""

from __future__ import annotations

import ctypes
import sys

# mallopt(3) parameters (glibc's malloc.h): parameter numbers, not values; origin: code/table, not a threshold.
M_TRIM_THRESHOLD = -1
M_MMAP_THRESHOLD = -3


def keep_image_buffers(mmap_mb: int = 32, trim_mb: int = 256) -> bool:
    """Blocks up to ``mmap_mb`` MiB come from the heap (not a fresh mapping each), and up to
    ``trim_mb`` MiB of freed heap stays with the process. Returns whether glibc took both (the
    second is not set where the first is refused)."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL("libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):  # not glibc (musl has no mallopt of these)
        return False
    mallopt.argtypes, mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
    return bool(mallopt(M_MMAP_THRESHOLD, mmap_mb << 20)) and bool(mallopt(M_TRIM_THRESHOLD, trim_mb << 20))
