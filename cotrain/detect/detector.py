"""The detector: ``cotrain detect [--model M.onnx] [--target T.yaml] IMAGES_OR_FOLDERS...`` and a Python API.

    det = Detector()                      # the shipped default model (its int8 dense maps for the grid pass)
    det = Detector(target=load_target("aprilgrid.yaml"))  # any target: the same Detection comes back
    found = det.detect(image)             # image: (H, W) or (H, W, 3|4), uint8 / uint16 / float
    found.ids, found.xy, found.confidence  # arrays, input-image pixels (docs/conventions.md)

An AprilGrid is found by the tag pass (:mod:`cotrain.detect.tag_pass`, no network). A checkerboard
by the network, with two ways to turn its outputs into identified corners:
- ``grid`` (default): the network's corner score and dense column / row maps feed the grid pass
  of :mod:`cotrain.detect.grid_pass` (saddle points at full resolution, lattice growth, one identity decision
  per board); corners are found at the input resolution, below the network's processing size.
- ``slots``: the network's own per-slot corners (one heatmap channel per id), kept when the
  visibility head says so and they sit in a consistent grid; ``polish`` refines them.

Reading images: :mod:`cotrain.detect.images`; the model and its named outputs:
:mod:`cotrain.detect.onnx_model`; the detection JSON over many files: :mod:`cotrain.io.detections`.
"""

from __future__ import annotations

import dataclasses
import os
from concurrent.futures import Executor, ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from cotrain.detect.grid_config import GridConfig
from cotrain.detect.grid_pass import BlackFrame, GridResult, black_frame, grid_pass, merge_half_resolution
from cotrain.detect.half_resolution import halve
from cotrain.detect.images import MIN_SIDE, ImageError, brighten, local_gain, to_grey_float
from cotrain.detect.onnx_model import OnnxModel, default_grid_model_path
from cotrain.detect.retries import Look, checkerboard_looks, first_found
from cotrain.detect.saddle import saddle_fit, smooth_for, window_half
from cotrain.detect.tag_config import TagConfig
from cotrain.detect.tag_pass import tag_pass
from cotrain.geometry.letterbox import Letterbox
from cotrain.model.outputs import DENSE_OUTPUTS, GRID_OUTPUTS, dense_maps
from cotrain.targets import AprilGrid, Checkerboard, Target

# Raised when a change of the code (not of the settings or the model) changes what the detectors
# report: detections cached under an older version are made again (see Detector.cache_key).
# 2: AprilGrid frames brightened; the grid pass's contrast thresholds scale with the board's contrast.
# 3: AprilGrid corners checked against the print; frames with few corners read at half resolution too.
# 4: AprilGrid tags read through a lens guessed from the image circle; seeds that decode grow first;
#    checkerboards completed from their identified corners.
# 5: the image circle found where a dark scene joins the black frame (more frames read through the lens).
# 6: the black frame found where a camera lifts its black level (saddle.black_level).
# 7: AprilGrid board coordinates in exact float64 (Target.board_xy; they were float32-rounded).
# 8: saddle fits compiled, with exact bilinear windows (fits move by up to 1e-4 px; a few growths and frames go otherwise).
# 9: completion's print fit in gaps under 10 px, at 0.7 of the variance through the lens, compiled; AprilGrid
#    candidates judged again under the map through them; AprilGrid frames that give nothing read a second time.
# 10: checkerboard frames of any size (not only a shorter side of 700 px) read at half resolution where nothing is found.
# 11: a checkerboard lattice's part cut at its margin is placed only where it adds evidence (grid_pass.cut_adds_evidence).
OUTPUT_VERSION = 11


def settings(cfg) -> dict:
    """A settings dataclass as plain values for a cache key written as strict JSON: a limit that
    is off (an infinite threshold, ``GridConfig.retry_min_margin``) is its string, "inf"."""

    def plain(v):
        if isinstance(v, dict):
            return {k: plain(x) for k, x in v.items()}
        if isinstance(v, (list, tuple)):
            return [plain(x) for x in v]
        return repr(v) if isinstance(v, float) and not np.isfinite(v) else v

    return plain(dataclasses.asdict(cfg))


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
    # The look of the target's retry schedule whose corners these are (cotrain.detect.retries): the one that found any, else the
    # first ("first" where nothing is found); "" in slot mode, which has no schedule.
    look: str = ""


@dataclass
class Pending:
    """An image between the two halves of a detector (:meth:`Detector.network`, :meth:`Detector.finish`)."""

    grey: np.ndarray  # (H, W) float32 input image
    box: Letterbox | None  # its letterbox into the processing size (None: no network)
    out: dict[str, np.ndarray]  # the network's outputs by name (empty: no network)
    frame: BlackFrame | None = None  # grey's black frame where read beside the network (Detector.detect), else None
    beside: Executor | None = None  # a thread idle while finish runs (Detector.detect's network thread), else None


def _default_grid_model(threads: int) -> OnnxModel:
    """The shipped graph the grid pass runs (:func:`default_grid_model_path`: the int8 dense maps),
    or the float graph where onnxruntime here cannot run the int8 one."""
    try:
        net = OnnxModel(default_grid_model_path(), threads)
        net.session  # noqa: B018 (an onnxruntime without these int8 kernels fails here)
        return net
    except ValueError:
        return OnnxModel(None, threads)


class Detector:
    """Identified corners at input resolution, for any target: ``Detector(target=...)``.

    What a target brings is how its corners are found and identified:
    - a checkerboard (:class:`~cotrain.targets.Checkerboard`): the network (onnxruntime, CPU) and
      the grid pass (:mod:`cotrain.detect.grid_pass`: saddles, lattice growth, one identity
      decision per board from margins, checker colours and the network's votes). Default target:
      the board the model was trained on. On another board than the model's, the network's corner
      and board maps still find the squares, but its column / row votes are for the other board, so
      the grid pass places the lattice from the geometry alone (docs/detector.md).
    - an AprilGrid (:class:`~cotrain.targets.AprilGrid`): the tag pass (:mod:`cotrain.detect.tag_pass`:
      X-junctions at full resolution, tags read through their own corners, one placement per
      board); no network is run, and ``model`` and the checkerboard's options are not used.

    Both give the same :class:`Detection` through the same two halves (:meth:`network`,
    :meth:`finish`; :func:`cotrain.io.detections.detect_files` overlaps them).
    """

    # Files per worker process below which detect_files keeps them in one process: starting two
    # costs about 2.5 s (imports, numba's kernels from its cache, the onnxruntime session), and
    # once started they win back about 7 ms per 1280x720 file over this process's two threads
    # (threads faster over 220 files, processes over 608; the same time near 360;
    # docs/benchmarks.md).
    files_per_worker = 180
    # The same for the tag pass: two spawned workers cost about 1.5 s to start and then take half
    # the time of one process (about 120 ms per 1280x720 file): over 8 / 16 / 32 / 64 evaluation
    # frames 1.95 / 2.22 / 3.61 / 5.31 s against 0.82 / 1.93 / 3.78 / 7.68 s, the same time near 28 files.
    files_per_worker_tags = 14

    def __init__(
        self,
        model: str | Path | None = None,
        threshold: float = 0.5,
        threads: int = 0,
        consistency: bool = True,
        polish: bool = False,
        mode: str = "grid",
        grid: GridConfig | None = None,
        target: Target | None = None,
        tags: TagConfig | None = None,
    ):
        if isinstance(target, AprilGrid):
            if mode == "slots":
                raise ValueError("slot mode reads a checkerboard network's per-slot corners; an AprilGrid is read by its tags")
            if mode != "grid":
                raise ValueError(f"mode must be 'grid' or 'slots', not {mode!r}")
            if grid is not None:
                raise ValueError("grid settings are the checkerboard's; an AprilGrid's tag pass takes TagConfig (tags=...)")
            self._init_tags(target, tags)
            return
        if target is not None and not isinstance(target, Checkerboard):
            raise ValueError(f"target: no detector finds a {target.kind} (checkerboards and aprilgrids)")
        self.tags = None
        self.net = _default_grid_model(threads) if model is None and mode == "grid" else OnnxModel(model, threads)
        self.path = self.net.path
        self.input_size = self.net.input_size  # (H, W)
        trained = self.net.target
        self.target: Target = target or trained
        if not isinstance(self.target, Checkerboard):
            raise ValueError(f"target: the model was trained on a {self.target.kind}; name the checkerboard to find")
        self.threshold = threshold
        self.consistency = consistency  # drop corners that sit in no consistent grid triple (see grid_consistent)
        self.polish = polish  # classical saddle-point polish of the final corners (see polish_corners)
        self.nx, self.ny = self.target.nx, self.target.ny
        self.board_votes = isinstance(trained, Checkerboard) and (trained.nx, trained.ny) == (self.nx, self.ny)
        if self.nx < 2 or self.ny < 2:
            raise ValueError(f"target: a checkerboard needs at least 3 x 3 squares, not {self.nx + 1} x {self.ny + 1}")
        if mode not in ("grid", "slots"):
            raise ValueError(f"mode must be 'grid' or 'slots', not {mode!r}")
        if mode == "grid" and not self.net.has_dense:
            mode = "slots"  # a model exported before the grid pass: no dense outputs
        if mode == "slots" and not self.net.has_slots:
            raise ValueError(f"{self.net.path}: the model has no per-slot outputs (a graph for the grid pass only)")
        if mode == "slots" and not self.board_votes:
            raise ValueError("slot mode reads the model's own corner ids: it needs the board the model was trained on")
        self.mode = mode
        self.grid = grid or GridConfig()
        # What the grid pass has the network compute: the dense maps, with the column / row maps as
        # logits where the graph gives them (their log-softmax is taken in finish, beside the network).
        self.dense = GRID_OUTPUTS if self.net.has_logits else DENSE_OUTPUTS
        if mode == "grid":
            self.net.keep(self.dense)  # the per-slot heads are not run
        self.net.session  # noqa: B018 (a model onnxruntime cannot load fails here, not on the first image)

    def _init_tags(self, target: AprilGrid, tags: TagConfig | None) -> None:
        """An AprilGrid's detector: the tag pass under ``tags`` (default :class:`TagConfig`), no network."""
        self.target, self.tags, self.mode = target, tags or TagConfig(), "tags"
        self.net = None
        self.path = "tag-pass"  # written as the detection JSON's "model": no network is involved
        self.files_per_worker = type(self).files_per_worker_tags

    def cache_key(self) -> dict:
        """What decides this detector's output (the model file and the settings): cached
        detections are reused only under the same key."""
        if self.tags is not None:
            return {"version": OUTPUT_VERSION, "tag_pass": settings(self.tags)}
        model = Path(self.path)
        return {
            "version": OUTPUT_VERSION,
            "model": [str(model.resolve()), model.stat().st_size, model.stat().st_mtime_ns],
            "mode": self.mode,
            "threshold": self.threshold,
            "consistency": self.consistency,
            "polish": self.polish,
            "grid": settings(self.grid),
        }

    def letterbox(self, grey: np.ndarray) -> Letterbox:
        """The letterbox of an (h, w) image into the model's processing size."""
        self._checkerboard_only("the network's letterbox")
        h, w = grey.shape
        return Letterbox(w, h, self.input_size)

    def _grey(self, image: np.ndarray) -> np.ndarray:
        grey = to_grey_float(image) if image.dtype != np.float32 or image.ndim != 2 else image
        h, w = grey.shape
        if min(h, w) < MIN_SIDE:
            raise ImageError(f"image too small ({w}x{h}); need at least {MIN_SIDE} px per side")
        return brighten(grey)

    def _grid(
        self,
        grey: np.ndarray,
        box: Letterbox,
        out: dict[str, np.ndarray],
        cfg: GridConfig,
        half: bool = True,
        frame: BlackFrame | None = None,
        beside: Executor | None = None,
    ) -> GridResult:
        """The grid pass on ``grey`` (its letterbox ``box``, the network's outputs ``out``, its black
        frame ``frame`` where already read, a thread idle meanwhile ``beside``); with
        ``half`` and ``cfg.half_resolution``, where it finds no corner (at any image size) and the
        network sees a board over ``cfg.half_min_board_share`` of its map, also at half resolution
        with the same network outputs (:func:`cotrain.detect.grid_pass.merge_half_resolution`: a
        board whose corners are too blurred at full resolution)."""
        out = dense_maps(out)
        logp_col, logp_row = out["col_logp"][0], out["row_logp"][0]
        if not self.board_votes:
            logp_col = np.zeros((self.nx + 2, *logp_col.shape[1:]), np.float32)
            logp_row = np.zeros((self.ny + 2, *logp_row.shape[1:]), np.float32)
        maps = (out["corner_prob"][0, 0], out["mask_prob"][0, 0], logp_col, logp_row)
        g = grid_pass(grey, box, *maps, self.target, cfg, frame=frame, beside=beside)
        h, w = grey.shape
        if not (half and cfg.half_resolution) or len(g.ids) or min(h, w) // 2 < MIN_SIDE:
            return g
        if np.mean(maps[1] > 0.5) < cfg.half_min_board_share:
            return g  # measured: no board under 0.4 % of the map was found at half resolution alone
        half_box = Letterbox(w // 2, h // 2, self.input_size)
        g_half = grid_pass(halve(grey), half_box, *maps, self.target, cfg, extent_rim_px=cfg.half_rim_px / 2, beside=beside)
        return merge_half_resolution(grey, g, g_half, self.target, cfg)

    def _grid_looks(
        self,
        grey: np.ndarray,
        box: Letterbox,
        out: dict[str, np.ndarray],
        cfg: GridConfig,
        frame: BlackFrame | None = None,
        beside: Executor | None = None,
    ) -> tuple[GridResult, Look]:
        """The grid pass by the checkerboard's retry schedule
        (:func:`cotrain.detect.retries.checkerboard_looks`): :meth:`_grid`, and where it finds
        nothing and ``cfg.retry_gain`` > 1, the same on ``grey`` with its contrast raised
        ``cfg.retry_gain`` times about its local mean (:func:`cotrain.detect.images.local_gain`),
        the network run again on it: a grey print, or a board in the shade or dim light, whose
        saddles and edges fall under the thresholds (set in intensity) and whose board the
        network does not see. The result of the first look that finds a corner, and that look.
        ``frame``: ``grey``'s black frame, where already read (the raised frame's is its own);
        ``beside``: a thread idle meanwhile (:func:`cotrain.detect.grid_pass.grid_pass`)."""

        def read(look: Look) -> GridResult:
            if not look.gained:
                return self._grid(grey, box, out, look.config(cfg), look.half_resolution, frame, beside)
            gained = local_gain(grey, cfg.retry_gain, cfg.retry_gain_sigma * min(grey.shape))
            return self._grid(gained, box, self._dense_maps(gained, box), look.config(cfg), look.half_resolution, beside=beside)

        return first_found(checkerboard_looks(cfg), read)

    def _checkerboard_only(self, what: str) -> None:
        if self.tags is not None:
            raise ValueError(f"{what} is the checkerboard's grid pass; an AprilGrid is read by the tag pass (detect)")

    def _dense_maps(self, grey: np.ndarray, box: Letterbox) -> dict[str, np.ndarray]:
        """The network's outputs the grid pass reads, on ``grey`` letterboxed by ``box``."""
        self._checkerboard_only("the network's dense maps")
        return self.net.run(box.apply(grey)[None, None], self.dense)

    def grid_result(self, image: np.ndarray, grid: GridConfig | None = None) -> GridResult:
        """The grid pass's whole result on one image (with its identity margin), under ``grid``
        (default the detector's own settings)."""
        self._checkerboard_only("grid_result")
        grey = self._grey(image)
        box = self.letterbox(grey)
        return self._grid_looks(grey, box, self._dense_maps(grey, box), grid or self.grid)[0]

    def detect(self, image: np.ndarray) -> Detection:
        """Detect corners in one image (any size, 8/16-bit or float, grey or colour).

        A checkerboard's network runs on a second thread (onnxruntime releases the GIL) while this
        one reads what needs only the image, its black frame (:func:`cotrain.detect.grid_pass.black_frame`);
        then, while the grid pass runs here, that thread makes the crop's distance to the rim and
        its blurs (:func:`cotrain.detect.grid_pass.grid_pass`'s ``beside``). The result is the
        same as :meth:`finish` of :meth:`network`, to the bit; :func:`cotrain.io.detections.detect_files`
        has its own overlap (the next image's network beside this one's grid pass)."""
        if self.tags is not None or self.mode != "grid":
            return self.finish(self.network(image))
        grey = self._grey(image)
        box = self.letterbox(grey)
        running = self._beside().submit(self.net.run, box.apply(grey)[None, None])
        frame = black_frame(grey)
        return self.finish(Pending(grey, box, running.result(), frame, self._beside()))

    def _beside(self) -> ThreadPoolExecutor:
        """The one thread :meth:`detect` runs the network on, made on first use, and anew in a
        forked process (whose copy of the executor has no thread behind it)."""
        if getattr(self, "_thread", None) is None or self._thread_pid != os.getpid():
            self._thread = ThreadPoolExecutor(max_workers=1, thread_name_prefix="cotrain-network")
            self._thread_pid = os.getpid()
        return self._thread

    def __getstate__(self) -> dict:
        """Pickled (to a worker process) without the network's thread: it is made there anew."""
        return {**self.__dict__, "_thread": None}

    def network(self, image: np.ndarray) -> Pending:
        """The first half of :meth:`detect`: the image letterboxed and through the network (no
        Python loops; onnxruntime releases the GIL, so another thread can run :meth:`finish` on
        the previous image meanwhile, see :func:`cotrain.io.detections.detect_files`)."""
        grey = self._grey(image)
        if self.tags is not None:
            return Pending(grey, None, {})  # the tag pass runs no network
        box = self.letterbox(grey)
        return Pending(grey, box, self.net.run(box.apply(grey)[None, None]))

    def finish(self, pending: Pending) -> Detection:
        """The second half of :meth:`detect`: the grid pass (or the per-slot read-out); with
        ``grid.retry_gain`` set, a frame giving nothing runs the network again here, on the frame
        with its contrast raised (:meth:`_grid_looks`)."""
        grey, box, out = pending.grey, pending.box, pending.out
        h, w = grey.shape
        if self.tags is not None:
            r = tag_pass(grey, self.target, self.tags)
            return Detection(r.ids, r.xy, r.confidence, np.ones(len(r.ids)), w, h, look=r.look)
        if self.mode == "grid":
            g, look = self._grid_looks(grey, box, out, self.grid, pending.frame, pending.beside)
            return Detection(g.ids, g.xy, g.confidence, np.ones(len(g.ids)), w, h, look=look.name)
        det = self._postprocess(out, box, consistency=self.consistency)
        if self.polish and len(det.ids):
            det.xy = polish_corners(grey, det.xy, local_square_px(det.ids, det.xy, self.nx))
        return det

    def _postprocess(self, out: dict[str, np.ndarray], box: Letterbox, consistency: bool = True) -> Detection:
        """The per-slot read-out of image 0 of ``out``, in input pixels."""
        vis, conf = out["visibility"][0], out["confidence"][0]
        w, h = box.width, box.height
        keep, xy = slot_readout(out, box, self.threshold)
        ids = np.nonzero(keep)[0]
        if consistency and len(ids):
            ids = ids[grid_consistent(ids, xy[ids], self.nx)]
        return Detection(ids, xy[ids], conf[ids].astype(np.float64), vis[ids].astype(np.float64), w, h, xy, vis)


def slot_readout(out: dict[str, np.ndarray], box: Letterbox, threshold: float) -> tuple[np.ndarray, np.ndarray]:
    """The network's per-slot corners of image 0 of ``out`` (its named outputs) in input pixels:
    keep (N,) bool, the slots whose visibility reaches ``threshold`` and whose corner lies in the
    input image, and xy (N, 2) of every slot."""
    xy = box.to_input(out["corners"][0].astype(np.float64))
    w, h = box.width, box.height
    inside = (xy[:, 0] > -0.5) & (xy[:, 0] < w - 0.5) & (xy[:, 1] > -0.5) & (xy[:, 1] < h - 0.5)
    return (out["visibility"][0] >= threshold) & inside & np.isfinite(xy).all(1), xy


def make_detector(target: Target | None, model: str | Path | None = None, **options) -> Detector:
    """``Detector(model, target=target, **options)``: the tag pass for an AprilGrid (it runs no
    network, so ``model`` is not used; slot mode and grid settings are one-line errors, the
    checkerboard's thresholds, threads and consistency options are not used), the network and the
    grid pass otherwise."""
    if isinstance(target, AprilGrid):
        kept = {k: options[k] for k in ("mode", "grid", "tags") if k in options}
        return Detector(target=target, **kept)
    return Detector(model, target=target, **options)


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
    window scaled to the local square size (:func:`cotrain.detect.saddle.saddle_fit`, without its
    X-junction tests). Corners whose fit is not a saddle, or that would move more than half the
    window, keep their position. (K, 2) -> (K, 2)."""
    out = np.asarray(xy, np.float64).copy()
    halves = np.atleast_1d(window_half(square_px))
    lenient = GridConfig(min_saddle_contrast=0.0, min_saddle_ratio=0.0, min_symmetry=-np.inf)
    for h in np.unique(halves):
        m = halves == h
        out[m] = saddle_fit(smooth_for(grey.astype(np.float32), int(h)), out[m], int(h), iterations, lenient)[0]
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
