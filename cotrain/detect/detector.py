"""The onnxruntime detector: ``cotrain detect [--model M.onnx] IMAGES_OR_FOLDERS...`` and a Python API.

    det = Detector()                      # the shipped default model
    found = det.detect(image)             # image: (H, W) or (H, W, 3|4), uint8 / uint16 / float
    found.ids, found.xy, found.confidence  # arrays, input-image pixels (CONVENTIONS convention)

Two ways to turn the network's outputs into identified corners:
- ``grid`` (default): the network's corner score and dense column / row maps feed the grid pass
  of :mod:`cotrain.detect.grid` (saddle points at full resolution, lattice growth, one identity decision
  per board); corners are found at the input resolution, below the network's processing size.
- ``slots``: the network's own per-slot corners (one heatmap channel per id), kept when the
  visibility head says so and they sit in a consistent grid; ``polish`` refines them.

An unreadable image becomes an entry with an ``error`` in the JSON and the run goes on.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from cotrain.detect.grid import GridConfig, grid_pass, saddle_fit, smooth_for, window_half

IMAGE_SUFFIXES = {".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".pgm", ".ppm", ".webp"}
MIN_SIDE = 16  # smaller images are rejected with an error entry


def default_model_path() -> Path:
    """The shipped model (installed with the package, in ``export/``)."""
    import export

    return Path(export.__file__).resolve().parent / "default.onnx"


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


@dataclass
class Detection:
    ids: np.ndarray  # (K,) corner ids
    xy: np.ndarray  # (K, 2) pixels of the input image
    confidence: np.ndarray  # (K,) confidence head (probability the corner is within ~0.5 px)
    visibility: np.ndarray  # (K,) visibility head
    width: int = 0
    height: int = 0
    all_xy: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))  # (N, 2) every slot, input pixels
    all_visibility: np.ndarray = field(default_factory=lambda: np.zeros(0))  # (N,)


class Detector:
    """onnxruntime inference on the CPU, pre- and post-processing as the model's metadata says.

    ``target`` ({"squares_x", "squares_y", "square_size"}, any of them) names another checkerboard
    than the model's: the grid pass then places the lattice from geometry alone (docs/detector.md).
    """

    def __init__(
        self,
        model: str | Path | None = None,
        threshold: float = 0.5,
        threads: int = 0,
        consistency: bool = True,
        polish: bool = False,
        mode: str = "grid",
        grid: GridConfig | None = None,
        target: dict | None = None,
    ):
        import onnxruntime as ort

        path = Path(model) if model else default_model_path()
        if not path.is_file():
            hint = "" if model else " (the shipped default model is missing; pass --model)"
            raise FileNotFoundError(f"{path}: model not found{hint}")
        opts = ort.SessionOptions()
        if threads:
            opts.intra_op_num_threads = threads
        try:
            self.session = ort.InferenceSession(str(path), opts, providers=["CPUExecutionProvider"])
        except Exception as e:
            raise ValueError(f"{path}: not a loadable ONNX model ({type(e).__name__})") from None
        meta = self.session.get_modelmeta().custom_metadata_map
        if "cotrain.input_size" not in meta:
            raise ValueError(f"{path}: not a cotrain model (no cotrain.input_size metadata)")
        self.path = path
        self.input_size = tuple(json.loads(meta["cotrain.input_size"]))  # (H, W)
        trained = json.loads(meta.get("cotrain.target", "{}"))
        self.target = {**trained, **(target or {})}
        self.threshold = threshold
        self.consistency = consistency  # drop corners that sit in no consistent grid triple (see grid_consistent)
        self.polish = polish  # classical saddle-point polish of the final corners (see polish_corners)
        self.nx = int(self.target.get("squares_x", 10)) - 1
        self.ny = int(self.target.get("squares_y", 7)) - 1
        # Another checkerboard than the model was trained on: its class-agnostic corner and board
        # maps still find the squares, but its column / row votes are for the other board, so the
        # grid pass places the lattice from the geometry alone (colours, extent, margin).
        self.board_votes = (self.nx + 1, self.ny + 1) == (int(trained.get("squares_x", 10)), int(trained.get("squares_y", 7)))
        if self.nx < 2 or self.ny < 2:
            raise ValueError(f"target: a checkerboard needs at least 3 x 3 squares, not {self.nx + 1} x {self.ny + 1}")
        if mode not in ("grid", "slots"):
            raise ValueError(f"mode must be 'grid' or 'slots', not {mode!r}")
        if mode == "grid" and len(self.session.get_outputs()) < 8:
            mode = "slots"  # a model exported before the grid pass: no dense outputs
        if mode == "slots" and not self.board_votes:
            raise ValueError("slot mode reads the model's own corner ids: it needs the board the model was trained on")
        self.mode = mode
        self.grid = grid or GridConfig()

    def preprocess(self, grey: np.ndarray) -> tuple[np.ndarray, float]:
        """Letterbox: scale to fit the processing size (INTER_AREA), top-left on black. -> (H, W), s."""
        H, W = self.input_size
        h, w = grey.shape
        s = min(W / w, H / h)
        nw, nh = max(1, round(w * s)), max(1, round(h * s))
        small = cv2.resize(grey, (nw, nh), interpolation=cv2.INTER_AREA if s < 1 else cv2.INTER_LINEAR)
        canvas = np.zeros((H, W), np.float32)
        canvas[:nh, :nw] = small[:H, :W]
        return canvas, s

    def run(self, batch: np.ndarray) -> list[np.ndarray]:
        """Raw model outputs for (B, 1, H, W) float32 processing-size images."""
        return self.session.run(None, {"image": batch.astype(np.float32)})

    def detect(self, image: np.ndarray) -> Detection:
        """Detect corners in one image (any size, 8/16-bit or float, grey or colour)."""
        grey = to_grey_float(image) if image.dtype != np.float32 or image.ndim != 2 else image
        h, w = grey.shape
        if min(h, w) < MIN_SIDE:
            raise ImageError(f"image too small ({w}x{h}); need at least {MIN_SIDE} px per side")
        x, s = self.preprocess(grey)
        out = self.run(x[None, None])
        corners, vis, conf = out[:3]
        det = self._postprocess(corners[0], vis[0], conf[0], s, w, h, consistency=self.consistency and self.mode == "slots")
        if self.mode == "grid":
            logp_col, logp_row = out[6][0], out[7][0]
            if not self.board_votes:
                logp_col = np.zeros((self.nx + 2, *logp_col.shape[1:]), np.float32)
                logp_row = np.zeros((self.ny + 2, *logp_row.shape[1:]), np.float32)
            g = grid_pass(grey, s, out[4][0, 0], out[5][0, 0], logp_col, logp_row, self.nx, self.ny, self.grid)
            det.ids, det.xy, det.confidence = g.ids, g.xy, g.confidence
            det.visibility = np.ones(len(g.ids))
        elif self.polish and len(det.ids):
            det.xy = polish_corners(grey, det.xy, local_square_px(det.ids, det.xy, self.nx))
        return det

    def _postprocess(
        self, corners: np.ndarray, vis: np.ndarray, conf: np.ndarray, s: float, w: int, h: int, consistency: bool = True
    ) -> Detection:
        xy = (corners.astype(np.float64) + 0.5) / s - 0.5
        inside = (xy[:, 0] > -0.5) & (xy[:, 0] < w - 0.5) & (xy[:, 1] > -0.5) & (xy[:, 1] < h - 0.5)
        keep = (vis >= self.threshold) & inside & np.isfinite(xy).all(1)
        ids = np.nonzero(keep)[0]
        if consistency and len(ids):
            ids = ids[grid_consistent(ids, xy[ids], self.nx)]
        return Detection(ids, xy[ids], conf[ids].astype(np.float64), vis[ids].astype(np.float64), w, h, xy, vis)


def grid_consistent(ids: np.ndarray, xy: np.ndarray, nx: int, rel_tol: float = 0.35, min_step_px: float = 2.0) -> np.ndarray:
    """Which corners sit in a locally consistent grid: (K,) bool.

    A corner is kept when it belongs to at least one triple of grid neighbours (i-1, i, i+1 along
    a row or a column) whose two steps agree: |d1 - d2| < rel_tol * max(|d1|, |d2|). Fisheye
    curvature over one square is small, so true neighbours pass; a corner with a wrong id lands
    far from where its id's neighbours are and takes part in no consistent triple. Steps shorter
    than ``min_step_px`` (corners collapsed onto each other) never count as consistent.
    """
    pos = {int(i): k for k, i in enumerate(ids)}
    keep = np.zeros(len(ids), dtype=bool)
    for k, i in enumerate(ids):
        gi, gj = int(i) % nx, int(i) // nx
        for di, dj in ((1, 0), (0, 1)):
            if not (0 <= gi - di and gi + di < nx and gj - dj >= 0):
                continue
            a, b = pos.get(int(i) - di - dj * nx), pos.get(int(i) + di + dj * nx)
            if a is None or b is None:
                continue
            d1, d2 = xy[k] - xy[a], xy[b] - xy[k]
            n1, n2 = np.linalg.norm(d1), np.linalg.norm(d2)
            if min(n1, n2) > min_step_px and np.linalg.norm(d1 - d2) < rel_tol * max(n1, n2):
                keep[[a, k, b]] = True
    return keep


def local_square_px(ids: np.ndarray, xy: np.ndarray, nx: int, default: float = 10.0) -> np.ndarray:
    """Per corner, the median distance (px) to its reported grid neighbours (default if none)."""
    pos = {int(i): k for k, i in enumerate(ids)}
    out = np.full(len(ids), default)
    for k, i in enumerate(ids):
        gi = int(i) % nx
        nb = [int(i) + d for d, ok in ((-1, gi > 0), (1, gi < nx - 1), (-nx, True), (nx, True)) if ok]
        d = [np.linalg.norm(xy[pos[j]] - xy[k]) for j in nb if j in pos]
        if d:
            out[k] = float(np.median(d))
    return out


def polish_corners(grey: np.ndarray, xy: np.ndarray, square_px: np.ndarray, iterations: int = 3) -> np.ndarray:
    """Classical sub-pixel polish: the saddle of a quadratic fitted to the smoothed image in a
    window scaled to the local square size (:func:`cotrain.detect.grid.saddle_fit`, without its
    X-junction tests). Corners whose fit is not a saddle, or that would move more than half the
    window, keep their position. (K, 2) -> (K, 2)."""
    out = np.asarray(xy, np.float64).copy()
    halves = np.atleast_1d(window_half(square_px))
    lenient = GridConfig(min_saddle_contrast=0.0, min_saddle_ratio=0.0, min_symmetry=-np.inf)
    for h in np.unique(halves):
        m = halves == h
        out[m] = saddle_fit(smooth_for(grey.astype(np.float32), int(h)), out[m], int(h), iterations, lenient)[0]
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


def draw_detection(grey: np.ndarray, det: Detection) -> np.ndarray:
    """BGR overlay: reported corners coloured by confidence, ids written every few corners."""
    im = cv2.cvtColor((np.clip(grey, 0, 1) * 255).astype(np.uint8), cv2.COLOR_GRAY2BGR)
    r = max(2, int(round(min(im.shape[:2]) / 250)))
    for i, (x, y), c in zip(det.ids, det.xy, det.confidence):
        col = (0, int(255 * c), int(255 * (1 - c)))
        cv2.circle(im, (int(round(x)), int(round(y))), r, col, -1, cv2.LINE_AA)
        if i % 9 == 0:
            cv2.putText(
                im, str(int(i)), (int(x) + r + 1, int(y) - r - 1), cv2.FONT_HERSHEY_SIMPLEX, 0.35 * r / 2, (0, 255, 255), 1, cv2.LINE_AA
            )
    return im


def detect_files(paths: list[Path], detector: Detector, draw_dir: Path | None = None, progress: bool = True) -> dict:
    """Run the detector over files; returns the detection JSON of CONVENTIONS (as a dict)."""
    from tqdm import tqdm

    entries = []
    if draw_dir is not None:
        draw_dir.mkdir(parents=True, exist_ok=True)
    for p in tqdm(paths, desc="detect", unit="img", disable=not progress or len(paths) < 2):
        entry = {"path": str(p), "width": 0, "height": 0, "corners": [], "error": None}
        try:
            grey = load_image(p)
            entry["height"], entry["width"] = grey.shape
            det = detector.detect(grey)
            entry["corners"] = [
                {"id": int(i), "x": round(float(x), 3), "y": round(float(y), 3), "confidence": round(float(c), 4)}
                for i, (x, y), c in zip(det.ids, det.xy, det.confidence)
            ]
            if draw_dir is not None:
                cv2.imwrite(str(draw_dir / (p.stem + "_det.png")), draw_detection(grey, det))
        except ImageError as e:
            entry["error"] = str(e)
        entries.append(entry)
    return {"model": str(detector.path), "target": detector.target, "images": entries}


def write_json_atomic(data: dict, out: Path) -> None:
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_suffix(out.suffix + ".tmp")
    tmp.write_text(json.dumps(data, indent=1))
    os.replace(tmp, out)
