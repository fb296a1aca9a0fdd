"""mrcal as a peer calibrator: its ``mrcal-calibrate-cameras`` tool on a corners file written from
our detections.

mrcal 2.2 comes as Debian packages (``mrcal`` for the tool, ``python3-mrcal`` for the system
python3); the PyPI name has no build for our Python. The project's venv never imports it: the tool
runs as a subprocess, and the models it writes are read back by a short script run with the system
python3. Where the tool is not installed, :func:`calibrate_mrcal` says so in its result and nothing
else changes.

The corners file is mrcal's vnlog ``# filename x y level``: one row per board point, row-major
(mrcal's board point (i, j) is our corner id ``j * nx + i``), ``- - -`` for a corner not detected
(a partial view), one file name ``camC/frameNNNNNN.png`` per observation, so that frame numbers
pair the cameras. mrcal's board point (i, j) sits at (i, j) x spacing, with the same axes as ours
and its origin at our corner 0 (docs/conventions.md puts corner 0 at one square in x and y), so
its board poses are ours after a shift by that corner's board coordinates. mrcal ignores corners
at negative pixel coordinates and observations with 3 corners or fewer; neither is written.

The default lens model is the one mrcal advises for wide lenses: a splined stereographic model over
the lens's FoV, seeded by mrcal's own stereographic seed with a focal length from ``--fov`` and
the observed image circle. mrcal seeds each board pose with OpenCV's pinhole solvePnP on the
stereographic-unprojected corners, which is where partial boards beyond 90 degrees off-axis fail.
"""

from __future__ import annotations

import glob
import json
import math
import os
import re
import shutil
import subprocess
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from cotrain.io.sequence import Sequence
from cotrain.targets import board_points

TOOL = "mrcal-calibrate-cameras"
SYSTEM_PYTHON = "/usr/bin/python3"
NOT_INSTALLED = "mrcal is not installed (Debian: apt-get install mrcal python3-mrcal)"


@dataclass
class MrcalConfig:
    lensmodel: str = ""  # mrcal lens model string; "" = splined stereographic over the FoV (mrcal's advice for wide lenses)
    knots: tuple[int, int] = (12, 8)  # spline knots (Nx, Ny) of the default model
    focal_px: float = 0.0  # stereographic focal length of the seed; 0 = from the FoV and the observed image circle
    timeout_s: float = 1800.0  # the tool is stopped (and the run counted as failed) after this long


@dataclass
class MrcalResult:
    available: bool  # the tool was found
    success: bool  # the tool ended normally and wrote a model per camera
    reason: str  # one line: why it failed ("" on success): mrcal's own last error line
    stage: str  # the last stage the tool announced (where it failed)
    runtime_s: float
    lensmodel: str
    rms_px: float = math.nan  # the tool's own final RMS (x and y counted apart, thrown-out corners as 0; also when it failed)
    rms_cam: list[float] = field(default_factory=list)  # per camera, RMS corner error (px) over the corners it kept: as ours
    outliers: int = 0  # corners the tool threw out
    intrinsics: list[list[float]] = field(default_factory=list)  # per camera, mrcal's order for its lens model
    T_cam_rig: np.ndarray | None = None  # (C, 4, 4); cam0 = rig
    T_rig_board: dict[int, np.ndarray] = field(default_factory=dict)  # view -> pose in our board frame
    q_rays: list[np.ndarray] = field(default_factory=list)  # per camera, (R, 2) projections of the rays asked for
    log: str = ""  # the tool's output


def mrcal_tool() -> str | None:
    """Path of ``mrcal-calibrate-cameras`` with the system python3 that can read its models, or None."""
    tool = shutil.which(TOOL)
    return tool if tool and Path(SYSTEM_PYTHON).is_file() else None


MIN_POINTS = 4  # mrcal keeps an observation with more than 3 valid corners


def write_corners(seq: Sequence, path: Path) -> list[int]:
    """Write ``seq``'s observations as mrcal's corners vnlog; returns the views in mrcal's frame
    order. Corners mrcal would ignore (negative coordinates) and observations it would drop (3
    corners or fewer) are left out, so that its frames are exactly these views."""
    board = seq.target
    n = board.n_corners
    lines = ["# filename x y level"]
    views = set()
    for o in sorted(seq.observations, key=lambda o: (o.view, o.cam)):
        ok = (o.q[:, 0] >= 0) & (o.q[:, 1] >= 0)
        if ok.sum() < MIN_POINTS:
            continue
        grid = np.full((n, 2), np.nan)
        grid[o.ids[ok]] = o.q[ok]
        name = f"cam{o.cam}/frame{o.view:06d}.png"
        lines += [f"{name} - - -" if np.isnan(x) else f"{name} {x:.4f} {y:.4f} 0" for x, y in grid]
        views.add(o.view)
    path.write_text("\n".join(lines) + "\n")
    return sorted(views)


def default_lensmodel(fov: float, cfg: MrcalConfig) -> str:
    nx, ny = cfg.knots
    return cfg.lensmodel or f"LENSMODEL_SPLINED_STEREOGRAPHIC_order=3_Nx={nx}_Ny={ny}_fov_x_deg={fov:.0f}"


def seed_focal(seq: Sequence, fov: float) -> float:
    """Stereographic focal length (px) that puts the rim of the FoV at the outermost observed corner."""
    r = 0.0
    for o in seq.observations:
        cam = seq.cameras[o.cam]
        c = np.array([(cam.width - 1) / 2, (cam.height - 1) / 2])
        r = max(r, float(np.linalg.norm(o.q - c, axis=-1).max()))
    return r / (2 * math.tan(math.radians(min(fov, 350.0)) / 4))


# Run with the system python3 (which has mrcal): reads the models, projects the rays asked for.
_READER = r"""
import json, sys
import numpy as np, mrcal
a = json.load(sys.stdin)
rays = np.array(a["rays"], dtype=float).reshape(-1, 3)
out = {"cams": []}
oi = mrcal.cameramodel(a["models"][0]).optimization_inputs()
x = mrcal.optimizer_callback(**oi, no_jacobian=True, no_factorization=True)[1]
ob = oi["observations_board"]
N, H, W, _ = ob.shape
r = x[: N * H * W * 2].reshape(N, H, W, 2)  # the board residuals lead the measurement vector
kept = ob[..., 2] > 0  # corners mrcal used (not missing, not thrown out)
cam_of = oi["indices_frame_camintrinsics_camextrinsics"][:, 1]
for i, path in enumerate(a["models"]):
    m = mrcal.cameramodel(path)
    lens, intr = m.intrinsics()
    q = mrcal.project(rays, lens, intr) if len(rays) else np.zeros((0, 2))
    rr = r[cam_of == i][kept[cam_of == i]]
    rms = float(np.sqrt(np.mean(np.sum(rr**2, -1)))) if len(rr) else float("nan")
    out["cams"].append({"lensmodel": lens, "intrinsics": intr.tolist(), "rt_cam_ref": m.extrinsics_rt_fromref().tolist(),
                        "q": np.where(np.isfinite(q), q, -1e9).tolist(), "rms": rms})
out["frames_rt_toref"] = oi["frames_rt_toref"].tolist()
json.dump(out, sys.stdout)
"""


def _T_from_rt(rt) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = cv2.Rodrigues(np.asarray(rt[:3], dtype=np.float64))[0]
    T[:3, 3] = rt[3:]
    return T


def _last(pattern: str, text: str) -> str:
    found = re.findall(pattern, text, flags=re.M)
    return found[-1].strip() if found else ""


def _reason(log: str, rc: int) -> str:
    """mrcal's own last error line (an exception message), or the exit status."""
    err = _last(r"^(?:[\w<>]+\.)*\w*(?:[Ee]rror|Exception)\w*: .*$", log)  # e.g. mrcal.calibration.<...>.<locals>.SolvePnPerror_negz: ...
    return err or _last(r"^Exception.*$", log) or f"{TOOL} exited with status {rc}"


def calibrate_mrcal(
    seq: Sequence, fov: float, cfg: MrcalConfig | None = None, rays: np.ndarray | None = None, workdir: Path | None = None
) -> MrcalResult:
    """Calibrate ``seq`` with mrcal's tool. ``rays`` (R, 3): camera-frame rays to project with the
    result (for a model-independent comparison). ``workdir`` keeps the corners file, the tool's log and
    its models (default: a temporary folder, removed)."""
    cfg = cfg or MrcalConfig()
    lensmodel = default_lensmodel(fov, cfg)
    tool = mrcal_tool()
    if tool is None:
        return MrcalResult(False, False, NOT_INSTALLED, "", 0.0, lensmodel)
    sizes = {(c.width, c.height) for c in seq.cameras}
    if len(sizes) != 1:
        return MrcalResult(True, False, f"{TOOL} takes one image size for every camera; this rig has {sorted(sizes)}", "", 0.0, lensmodel)
    (w, h), board = sizes.pop(), seq.target
    if getattr(board, "kind", "") != "checkerboard":
        return MrcalResult(True, False, f"{TOOL} takes chessboards; this target is a {board.kind}", "", 0.0, lensmodel)
    tmp = None
    if workdir is None:
        tmp = tempfile.TemporaryDirectory(prefix="mrcal_")
        workdir = Path(tmp.name)
    workdir.mkdir(parents=True, exist_ok=True)
    try:
        views = write_corners(seq, workdir / "corners.vnl")
        focal = cfg.focal_px or seed_focal(seq, fov)
        # fmt: off
        where = glob.escape(str(workdir.resolve()))  # absolute globs: a folder named cam0 above cannot confuse mrcal
        cmd = [tool, "--corners-cache", "corners.vnl", "--lensmodel", lensmodel, "--focal", f"{focal:.2f}",
               "--imagersize", str(w), str(h), "--object-spacing", f"{board.spacing:.9g}",
               "--object-width-n", str(board.nx), "--object-height-n", str(board.ny), "--outdir", "models",
               *[f"{where}/cam{c}/*.png" for c in range(len(seq.cameras))]]
        # fmt: on
        (workdir / "models").mkdir(exist_ok=True)
        t0 = time.time()
        try:
            env = {**os.environ, "PYTHONUNBUFFERED": "1"}  # its stdout and stderr interleave in order
            pipes = dict(stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
            p = subprocess.run(cmd, cwd=workdir, timeout=cfg.timeout_s, env=env, **pipes)
            log, rc = p.stdout, p.returncode
        except subprocess.TimeoutExpired as e:
            out = e.stdout.decode(errors="replace") if isinstance(e.stdout, bytes) else (e.stdout or "")
            log, rc = f"{out}\nTimeoutError: stopped after {cfg.timeout_s:.0f} s", -1
        runtime = time.time() - t0
        (workdir / "mrcal.log").write_text(" ".join(cmd) + "\n\n" + log)
        stage = _last(r"^(?:## (?!RMS)|=+ )(.*?)$", log)
        rms = _last(r"^## RMS error: ([0-9.eE+-]+)", log)
        n_out = _last(r"Noutliers: (\d+)", log)
        res = MrcalResult(
            available=True,
            success=False,
            reason="",
            stage=stage,
            runtime_s=runtime,
            lensmodel=lensmodel,
            rms_px=float(rms) if rms else math.nan,
            outliers=int(n_out) if n_out else 0,
            log=log,
        )
        models = [workdir / "models" / f"camera-{c}.cameramodel" for c in range(len(seq.cameras))]
        if rc != 0 or not all(m.is_file() for m in models):
            res.reason = _reason(log, rc)
            return res
        rays = np.zeros((0, 3)) if rays is None else np.asarray(rays, dtype=np.float64)
        try:
            p = subprocess.run(
                [SYSTEM_PYTHON, "-c", _READER],
                input=json.dumps({"models": [str(m) for m in models], "rays": rays.tolist()}),
                capture_output=True,
                text=True,
                timeout=600,
            )
        except subprocess.TimeoutExpired:
            res.reason = "reading mrcal's models took over 600 s"
            return res
        if p.returncode != 0:
            res.reason = "reading mrcal's models failed: " + (p.stderr.strip().splitlines() or ["?"])[-1]
            return res
        d = json.loads(p.stdout)
        if len(d["frames_rt_toref"]) != len(views):
            res.reason = f"mrcal kept {len(d['frames_rt_toref'])} of the {len(views)} views written; its board poses cannot be paired"
            return res
        res.rms_cam = [c["rms"] for c in d["cams"]]
        res.intrinsics = [c["intrinsics"] for c in d["cams"]]
        res.T_cam_rig = np.stack([_T_from_rt(c["rt_cam_ref"]) for c in d["cams"]])
        shift = np.eye(4)
        shift[:3, 3] = -board_points(board)[0]  # our board frame -> mrcal's (origin at corner 0)
        res.T_rig_board = {v: _T_from_rt(rt) @ shift for v, rt in zip(views, d["frames_rt_toref"])}
        res.q_rays = [np.asarray(c["q"], dtype=np.float64).reshape(-1, 2) for c in d["cams"]]
        res.success = True
        return res
    finally:
        if tmp is not None:
            tmp.cleanup()
