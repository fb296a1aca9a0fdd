"""Images as the detector takes them: files read and converted to grey float32 in [0, 1].

An unusable image raises :class:`ImageError` with a one-line reason, so work over many files
records it and goes on.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

IMAGE_SUFFIXES = {".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".pgm", ".ppm", ".webp"}
# origin: not recorded (set in 257b4ca, "ONNX export ...; onnxruntime detector (cotrain detect) with error entries")
MIN_SIDE = 16  # px, the shorter side: smaller images are rejected with an error entry


class ImageError(ValueError):
    """An image that cannot be used (one-line reason)."""


def to_grey_float(img: np.ndarray) -> np.ndarray:
    """8- or 16-bit (or float), grey, colour or with alpha -> (H, W) float32 grey in [0, 1]."""
    if img.ndim == 3 and img.shape[2] == 1:
        img = img[..., 0]
    if img.ndim == 3:
        if img.shape[2] == 4:
            img = img[..., :3]
        if img.shape[2] != 3:
            raise ImageError(f"unsupported channel count {img.shape[2]}")
        img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
    if img.ndim != 2:
        raise ImageError(f"unsupported image shape {img.shape}")
    if img.dtype == np.uint8:
        return img.astype(np.float32) / 255.0
    if img.dtype == np.uint16:
        return img.astype(np.float32) / 65535.0
    if np.issubdtype(img.dtype, np.floating):
        return np.clip(img.astype(np.float32), 0.0, 1.0)
    raise ImageError(f"unsupported pixel type {img.dtype}")


def brighten(grey: np.ndarray, below: float = 0.25, target: float = 0.9, max_gain: float = 6.0) -> np.ndarray:
    """An under-exposed frame scaled up: when the 99th percentile of (H, W) float32 grey (of the
    pixels brighter than the black frame around an image circle) is under ``below``, the frame
    times the gain that brings it to ``target``, at most ``max_gain``; any other frame is returned
    as it is (frames at 0.3-0.9 were found as well without the gain, and with it some were placed
    differently: only the truly dark ones are changed).

    The grid pass's thresholds are intensities (saddle contrast, colour contrast, saddle
    response), and the network was trained on exposures of 0.6-1.4: a frame exposed at a fifth of
    that would fall below them. A gain moves no saddle point, and zero (the black outside the
    circle) stays zero."""
    sample = grey[::4, ::4]
    lit = sample[sample > 0.02]
    if lit.size < 64:
        return grey
    p99 = float(np.percentile(lit, 99))
    if p99 >= below or p99 <= 0:
        return grey
    return np.minimum(grey * min(target / p99, max_gain), 1.0).astype(np.float32)


def local_gain(grey: np.ndarray, gain: float, sigma: float) -> np.ndarray:
    """(H, W) float32 ``grey`` with its contrast about the local mean (a Gaussian of ``sigma`` px)
    raised ``gain`` times, clipped to [0, 1]: a linear stretch that keeps where the X-junctions are
    (the mean varies slowly across a corner's window) except where it clips. Where ``sigma`` is 8
    px or more, the mean is taken at a quarter of the resolution and interpolated back: for a
    1280x720 frame at sigma 20 the mean costs 1 ms instead of 24 (the whole stretch 4.5 ms against
    31), within 0.005 of the full-resolution Gaussian inside the frame (up to 0.015 within a few
    sigma of its edges on small frames). Raises ValueError for a sigma that is not positive."""
    if not (sigma > 0 and np.isfinite(sigma)):
        raise ValueError(f"local_gain: sigma must be a positive number of pixels, not {sigma}")
    g = np.asarray(grey, np.float32)
    h, w = g.shape
    f = 4 if min(h, w) >= 64 and sigma >= 8 else 1
    small = cv2.resize(g, (w // f, h // f), interpolation=cv2.INTER_AREA) if f > 1 else g
    mean = cv2.GaussianBlur(small, (0, 0), sigma / f)
    if f > 1:
        mean = cv2.resize(mean, (w, h), interpolation=cv2.INTER_LINEAR)
    out = cv2.addWeighted(g, float(gain), mean, 1.0 - float(gain), 0.0)
    return np.clip(out, 0, 1, out=out)


def load_image(path: str | Path) -> np.ndarray:
    """Read an image file as grey float32 in [0, 1]; raises :class:`ImageError` with the reason."""
    p = Path(path)
    if not p.exists():
        raise ImageError("file not found")
    if p.is_dir():
        raise ImageError("is a folder")
    if p.stat().st_size == 0:
        raise ImageError("empty file")
    img = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise ImageError("not a readable image (corrupt or unsupported format)")
    return to_grey_float(img)


def image_folders_below(folder: Path, depth: int = 2) -> list[Path]:
    """Folders under ``folder`` (up to ``depth`` levels down, sorted) that hold images: what a user
    who named a recording's top folder meant (``cotrain detect`` reads a folder's own images only)."""
    out = []
    try:
        subs = sorted(q for q in folder.iterdir() if q.is_dir())
    except OSError:  # unreadable: nothing to suggest there
        return out
    for sub in subs:
        try:
            holds = any(f.suffix.lower() in IMAGE_SUFFIXES and f.is_file() for f in sub.iterdir())
        except OSError:
            continue
        if holds:
            out.append(sub)
        elif depth > 1:
            out.extend(image_folders_below(sub, depth - 1))
    return out


def expand_inputs(items: list[str]) -> list[Path]:
    """Files as given; folders expanded to their images (sorted). Missing paths are kept (they
    become error entries)."""
    out: list[Path] = []
    for it in items:
        p = Path(it)
        if p.is_dir():
            out.extend(sorted(q for q in p.iterdir() if q.suffix.lower() in IMAGE_SUFFIXES and q.is_file()))
        else:
            out.append(p)
    return out
