"""The detection JSON (docs/conventions.md): written by ``cotrain detect``, read by every evaluator.

Work over many files goes on past a bad one: an unreadable image becomes an entry with an
``error`` and no corners.
"""

from __future__ import annotations

import json
import math
import multiprocessing
import os
from concurrent.futures import ProcessPoolExecutor, ThreadPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path

import cv2
import numpy as np

from cotrain.detect.buffers import keep_image_buffers
from cotrain.detect.detector import Detector, draw_detection
from cotrain.detect.images import ImageError, load_image
from cotrain.progress import progress_bar

LOOKAHEAD = 2  # images read and through the network ahead of the one the grid pass works on
MAX_WORKERS = 8  # worker processes at most (workers=0: one per core up to this)


def detect_files(paths: list[Path], detector: Detector, draw_dir: Path | None = None, progress: bool = True, workers: int = 1) -> dict:
    """Run the detector over files; returns the detection JSON of docs/conventions.md (as a dict).

    With ``workers`` other than 1 (0: one per core, at most :data:`MAX_WORKERS`) and enough files
    (the detector's ``files_per_worker`` per process; with fewer, fewer processes), worker processes
    detect files side by side, each with its own copy of the detector (the network at one
    onnxruntime thread per core it has). They are spawned: a script that calls this with
    ``workers != 1`` needs Python's ``if __name__ == "__main__":`` guard. The commands (``cotrain
    detect``, ``calib-eval``, the main job) pass 0. Otherwise the files are detected in this
    process with two images in flight: while the grid pass (or the tag pass) works on one image, a
    second thread reads the next one and runs it through the network (decoding and onnxruntime
    release the GIL; the passes, Python, mostly hold it). The output is the same either way; a
    file that cannot be read is an entry with its error, and a worker that dies stops the run with
    a one-line :class:`ChildProcessError`."""
    if draw_dir is not None:
        draw_dir.mkdir(parents=True, exist_ok=True)
    keep_image_buffers()  # many images in this process (or its workers): their buffers are reused
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)  # a container's share
    n_proc = min(cores, MAX_WORKERS) if workers == 0 else workers
    n_proc = min(n_proc, len(paths) // detector.files_per_worker)
    bar = dict(desc="detect", unit="img", total=len(paths), enabled=progress and len(paths) > 1)
    entries = []
    if n_proc > 1:
        # Spawned, not forked: the caller may hold torch or onnxruntime threads.
        ctx = multiprocessing.get_context("spawn")
        threads = max(1, cores // n_proc)
        try:
            with ProcessPoolExecutor(n_proc, mp_context=ctx, initializer=_start_worker, initargs=(detector, threads)) as pool:
                jobs = [pool.submit(_detect_in_worker, p, draw_dir) for p in paths]
                try:
                    entries = [job.result() for job in progress_bar(jobs, **bar)]
                except BaseException:
                    pool.shutdown(wait=False, cancel_futures=True)  # an error or Ctrl+C stops the files not begun
                    raise
        except BrokenProcessPool:
            raise ChildProcessError(
                "a detection worker process stopped (killed, out of memory, or started from a script without "
                "if __name__ == '__main__'); --workers 1 detects in this process"
            ) from None
        return {"model": str(detector.path), "target": detector.target.to_json(), "images": entries}

    def front(p: Path):
        return detector.network(load_image(p))

    # The second thread keeps a core busy with reading and the network: OpenCV's own threads in
    # the grid pass would only contend with it (measured: 34.5 -> 32.9 ms per 1280x720 file).
    cv_threads = cv2.getNumThreads()
    cv2.setNumThreads(1)
    try:
        with ThreadPoolExecutor(max_workers=1) as pool:
            ahead = [pool.submit(front, p) for p in paths[:LOOKAHEAD]]
            for k, p in enumerate(progress_bar(paths, **bar)):
                if k + LOOKAHEAD < len(paths):
                    ahead.append(pool.submit(front, paths[k + LOOKAHEAD]))
                entries.append(_entry(detector, p, ahead[k].result, draw_dir))
                ahead[k] = None  # the image is not kept once it is done
    finally:
        cv2.setNumThreads(cv_threads)
    return {"model": str(detector.path), "target": detector.target.to_json(), "images": entries}


def _entry(detector: Detector, p: Path, pending, draw_dir: Path | None) -> dict:
    """One file's entry of the detection JSON; ``pending()`` gives the image through the first
    half of the detector (:meth:`Detector.network`), or raises :class:`ImageError`."""
    entry = {"path": str(p), "width": 0, "height": 0, "corners": [], "error": None}
    try:
        got = pending()
        entry["height"], entry["width"] = got.grey.shape
        det = detector.finish(got)
        entry["corners"] = [
            {"id": int(i), "x": round(float(x), 3), "y": round(float(y), 3), "confidence": round(float(c), 4)}
            for i, (x, y), c in zip(det.ids, det.xy, det.confidence)
        ]
        if draw_dir is not None:
            cv2.imwrite(str(draw_dir / (p.stem + "_det.png")), draw_detection(got.grey, det))
    except ImageError as e:
        entry["error"] = str(e)
    return entry


_worker_detector: Detector | None = None  # a worker process's own detector


def _start_worker(detector: Detector, threads: int) -> None:
    """A worker process's start in :func:`detect_files`: keep its copy of the detector (sent once
    per process, not per file), its network at ``threads`` onnxruntime threads and OpenCV at as many."""
    global _worker_detector
    keep_image_buffers()
    cv2.setNumThreads(threads)  # the processes share the cores: OpenCV's threads would contend across them
    if detector.net is not None:  # (the tag pass runs no network)
        detector.net.threads = threads
    _worker_detector = detector


def _detect_in_worker(p: Path, draw_dir: Path | None) -> dict:
    """A worker process's job in :func:`detect_files`: one file, read and detected."""
    det = _worker_detector
    return _entry(det, p, lambda: det.network(load_image(p)), draw_dir)


def json_safe(obj):
    """``obj`` with NaN and infinities as None (JSON has no such numbers) and numpy scalars and
    arrays as plain Python values, for ``json.dumps``."""
    if isinstance(obj, dict):
        return {k: json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_safe(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return json_safe(obj.tolist())
    if isinstance(obj, (np.floating, np.integer, np.bool_)):
        obj = obj.item()
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj


def write_json_atomic(data: dict, out: Path) -> None:
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_suffix(out.suffix + ".tmp")
    tmp.write_text(json.dumps(data, indent=1))
    os.replace(tmp, out)
