"""AprilGrid detection evaluation: ``python -m calib_eval.detection.tags [--per-fov N] [--fov ...] [--size WxH] [--out DIR]``.

1. Render a seeded AprilGrid set (Kalibr's 6 x 6 default, 1280x720 or ``--size``, half f-theta kb4, half the
   other families, partial views included, plus frames without a target), with the same realism
   as the checkerboard set (:mod:`calib_eval.detection.evaluation`).
2. Run our tag pass (:class:`cotrain.detect.detector.Detector`) and the AprilGrid
   detectors a user would otherwise pick, where installed (``make peers``): OpenCV's aruco with
   ``DICT_APRILTAG_36h11`` and Kalibr's 2-bit border, ``aprilgrid`` (PyPI, a port of Kalibr's
   detector) and ``pupil-apriltags`` (AprilTag 3), each peer in a process of its own
   (:func:`run_peers`: a crash in a peer's library ends that peer's row, not the evaluation).
3. Score per FoV, per 10-degree bin of the corner's off-axis angle and per bin of tag size, and
   on rows of hard frames of their own (``--per-condition``): the checkerboard evaluation's
   conditions (:data:`calib_eval.detection.conditions.CONDITIONS`: large tags at the rim, over- and
   under-exposure, a dull print, motion blur, strong vignetting, glare), FoV drawn in 180-240 deg.

Detectable corners: visible, and the tag at least ``min_tag_px`` across (the smaller singular
value of the image of one tag side). A peer's tag gives its four corners the ids of that tag's
Kalibr corners, matched to the labels of that tag by position (peers order corners differently);
a corner is recalled within 3 px of its label. A corner reported with its id within 3 px of a
corner the labels call hidden (an occluder within 2 px of it, glare that washes it out) is
counted apart ("labelled hidden": its id and position are right, the labels' visibility is
conservative); every other reported corner is wrong.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
import torch

from calib_eval.detection.conditions import CONDITIONS
from calib_eval.detection.evaluation import TOL_PX, _render_cfg, parse_size
from calib_eval.detection.sets import cache_key, describe, set_seed
from cotrain.detect.buffers import keep_image_buffers
from cotrain.detect.detector import Detector
from cotrain.geometry import cameras
from cotrain.progress import progress_bar
from cotrain.render.renderer import LABEL_VERSION, render_batch
from cotrain.targets import AprilGrid, TargetConfig, make_target

BINS = list(range(0, 120, 10))  # off-axis bins, deg: [0, 10) ... [110, 120)
SIZES = [5, 8, 10, 12, 16, 20, 30]  # tag-size bins, px across: [5, 8) ... [30, inf); tags under min_tag_px are visible, not detectable


@dataclass
class TagEvalConfig:
    fovs: list[int] = field(default_factory=lambda: [180, 200, 220, 240])  # FoVs (deg)
    per_fov: int = 50  # frames per FoV
    n_empty: int = 10  # frames without a target
    conditions: list[str] = field(default_factory=lambda: list(CONDITIONS))  # rows of hard frames (CONDITIONS)
    per_condition: int = 16  # frames per condition (0: none)
    seed: int = 2027  # the set's seed
    min_tag_px: float = 8.0  # detectable: the tag at least this many px across
    width: int = 1280
    height: int = 720


# --------------------------------------------------------------------------------------------
# Peers: each returns [(tag id, (4, 2) corners)] for a uint8 image
# --------------------------------------------------------------------------------------------
def _aruco():
    prm = cv2.aruco.DetectorParameters()
    prm.markerBorderBits = 2
    prm.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    det = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_APRILTAG_36h11), prm)

    def run(img):
        corners, ids, _ = det.detectMarkers(img)
        return [] if ids is None else [(int(t), c.reshape(4, 2)) for t, c in zip(ids.ravel(), corners)]

    return run


def _aprilgrid():
    from aprilgrid import Detector

    det = Detector("t36h11")
    return lambda img: [(int(d.tag_id), np.asarray(d.corners, np.float64).reshape(4, 2)) for d in det.detect(img)]


def _pupil():
    from pupil_apriltags import Detector

    det = Detector(families="tag36h11", quad_decimate=1.0, refine_edges=True)
    return lambda img: [(int(d.tag_id), np.asarray(d.corners, np.float64).reshape(4, 2)) for d in det.detect(img)]


PEERS = {"aruco": _aruco, "aprilgrid": _aprilgrid, "pupil-apriltags": _pupil}


def peer_tags(make: Callable, paths: list[str]) -> list[tuple[list, float]]:
    """The detector ``make()`` builds (one of :data:`PEERS`, or ours) over the images ``paths``
    (read as 8-bit grey; the reading is not timed): per image what it returns and its
    milliseconds. Raises ImportError where a peer is not installed."""
    run = make()
    keep_image_buffers()  # as cotrain detect runs (cotrain.detect.buffers), for every detector timed here
    out = []
    for path in paths:
        img = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        t0 = time.perf_counter()
        tags = run(img)
        out.append((tags, 1000 * (time.perf_counter() - t0)))
    return out


def run_peers(paths: list[Path], peers: dict[str, Callable] | None = None, progress: bool = True) -> dict[str, list[tuple[list, float]]]:
    """:func:`peer_tags` of every peer (name -> factory, module-level; default :data:`PEERS`) over
    ``paths``, each in a process of its own (spawned), one after another: name -> per image its
    tags and milliseconds. A peer is a third-party library, some of them C (AprilTag's, under
    pupil-apriltags, has an open report of heap corruption: pupil-labs/apriltags#39). With all
    of them in one process, a 10 x 8 AprilGrid set of the independent renderer aborted in a later
    allocation in 5 of 5 runs; with each in its own, in none of 3. A peer whose process dies is
    left out of this run, said in one line, and the others and our detector's results stand. A
    peer not installed is left out too (said on stderr)."""
    from concurrent.futures import ProcessPoolExecutor
    from concurrent.futures.process import BrokenProcessPool
    from multiprocessing import get_context

    out = {}
    for name, make in (PEERS if peers is None else peers).items():
        if progress:
            print(f"{name}: {len(paths)} images, in a process of its own", file=sys.stderr)
        with ProcessPoolExecutor(1, mp_context=get_context("spawn")) as pool:
            try:
                out[name] = pool.submit(peer_tags, make, [str(p) for p in paths]).result()
            except ImportError:
                print(f"{name}: not installed (make peers); left out", file=sys.stderr)
            except BrokenProcessPool:
                print(f"{name}: its process died (a crash inside the library); left out of this run", file=sys.stderr)
    return out


# --------------------------------------------------------------------------------------------
# Set
# --------------------------------------------------------------------------------------------
def render_frame(cfg: TagEvalConfig, ecfg, fov: int | None, condition: str | None, i: int) -> tuple[dict, object, str]:
    """Frame ``i`` of the set: of FoV ``fov`` (0: without a target) or of ``condition`` (then
    ``fov`` None), rendered for the evaluation config ``ecfg`` (its size and target). Half the
    frames per FoV through f-theta kb4, half through the other families. Returns the renderer's
    batch of one, its render config and the frame's file name. The frames' seeds come from
    :func:`calib_eval.detection.sets.set_seed` (the set's seed at 1280x720, mixed with the size elsewhere)."""
    base = set_seed(cfg.seed, cfg.width, cfg.height)
    if condition:
        rc = _render_cfg((180.0, 240.0), ecfg, list(cameras.MODELS), condition=condition)
        b = render_batch(rc, [i], seed=base * 1000 + 50 + list(CONDITIONS).index(condition))
        return b, rc, f"{condition.replace(' ', '_').replace('-', '_')}_{i:03d}.png"
    others = [m for m in cameras.MODELS if m != "kb4"]
    models = list(cameras.MODELS) if fov == 0 else (["kb4"] if i < cfg.per_fov // 2 else others)
    rc = _render_cfg(fov or 200, ecfg, models, no_target=fov == 0)
    b = render_batch(rc, [i], seed=base * 1000 + (fov // 10))
    return b, rc, f"{'empty' if fov == 0 else f'fov{fov}'}_{i:03d}.png"


def render_set(cfg: TagEvalConfig, board: AprilGrid, out: Path) -> list[dict]:
    """Render the set into ``out/images`` (cached with its labels in ``out/labels.json``)."""
    lab_path = out / "labels.json"
    key = {"config": cfg.__dict__, "target": board.to_json(), "label_version": LABEL_VERSION, **cache_key(cfg.width, cfg.height)}
    if lab_path.is_file():
        old = json.loads(lab_path.read_text())
        if old.get("key") == key:
            return old["labels"]
    (out / "images").mkdir(parents=True, exist_ok=True)
    from calib_eval.detection.evaluation import EvalConfig

    ecfg = EvalConfig(width=cfg.width, height=cfg.height, target=board.cfg)
    unknown = [c for c in cfg.conditions if c not in CONDITIONS]
    if unknown:
        raise ValueError(f"unknown condition {unknown[0]!r} (known: {', '.join(CONDITIONS)})")
    # (FoV, condition, index): FoV 0 is a frame without a target, None one of a condition's.
    jobs = [(fov, None, i) for fov in cfg.fovs for i in range(cfg.per_fov)] + [(0, None, i) for i in range(cfg.n_empty)]
    jobs += [(None, c, i) for c in cfg.conditions for i in range(cfg.per_condition)]
    labels = []
    for fov, condition, i in progress_bar(jobs, desc="render aprilgrid set", unit="img"):
        b, rc, name = render_frame(cfg, ecfg, fov, condition, i)
        cv2.imwrite(str(out / "images" / name), (b["image"][0, 0].numpy() * 255).round().astype(np.uint8))
        model = rc.models[int(b["model_index"][0])]
        p_cam = b["T_cam_board"][0, :3, :3] @ board.points(b["T_cam_board"].dtype).T + b["T_cam_board"][0, :3, 3:]
        angle = torch.rad2deg(torch.atan2(p_cam[:2].norm(dim=0), p_cam[2]))
        labels.append(
            {
                "image": name,
                "fov": fov or None,
                "condition": condition,
                "model": model,
                "corners": b["corners_raw"][0].tolist(),
                "visible": b["visible"][0].tolist(),
                "tag_px": b["square_px"][0].tolist(),
                "angle": angle.tolist(),
            }
        )
    lab_path.write_text(json.dumps({"key": key, "labels": labels}))
    return labels


# --------------------------------------------------------------------------------------------
# Scoring
# --------------------------------------------------------------------------------------------
def tags_to_corners(tags: list, board: AprilGrid, q: np.ndarray) -> tuple[list[int], list[np.ndarray]]:
    """A peer's tags -> (ids, positions): each tag's four corners take the ids of its Kalibr corners,
    matched to that tag's labels ``q`` (N, 2) by position; tags not on the board give wrong corners
    (id -1)."""
    ids, xy = [], []
    for t, c in tags:
        if not 0 <= t < board.n_tags:
            ids += [-1] * 4
            xy += list(c)
            continue
        kal = board.tag_corners(t)
        for p in c:
            ids.append(int(kal[np.argmin(np.linalg.norm(q[kal] - p, axis=1))]))
            xy.append(p)
    return ids, xy


def score_frame(ids, xy, lab: dict, min_tag_px: float) -> dict:
    q, vis = np.array(lab["corners"]), np.array(lab["visible"], bool)
    det = vis & (np.array(lab["tag_px"]) >= min_tag_px)
    hit = np.zeros(len(q), bool)
    err, wrong, hidden = [], 0, 0
    for i, p in zip(ids, xy):
        near = 0 <= i < len(q) and np.linalg.norm(q[i] - p) < TOL_PX
        if near and vis[i] and not hit[i]:
            hit[i] = True
            if det[i]:
                err.append(float(np.linalg.norm(q[i] - p)))
        elif near and not vis[i]:
            hidden += 1  # its own id at a corner the labels call hidden (an occluder within 2 px of it)
        else:
            wrong += 1
    return {"det": det, "hit": hit & det, "vis": vis, "found": hit, "err": err, "wrong": wrong, "hidden": hidden}


def evaluate(cfg: TagEvalConfig, out: Path) -> dict:
    board = make_target(TargetConfig(kind="aprilgrid"))
    labels = render_set(cfg, board, out)
    paths = [out / "images" / lab["image"] for lab in labels]

    def ours():  # the tag pass, in this process: (ids, positions) per image
        detect = Detector(target=board).detect
        return lambda img: (lambda d: (d.ids.tolist(), list(d.xy)))(detect(img))

    runs = {"ours": peer_tags(ours, paths), **run_peers(paths)}
    res = {}
    for name, found in runs.items():
        rows = []
        for lab, (tags, ms) in zip(labels, found):
            ids, xy = tags if name == "ours" else tags_to_corners(tags, board, np.array(lab["corners"]))
            s = score_frame(ids, xy, lab, cfg.min_tag_px)
            rows.append((lab, s, ms, len(ids)))
        res[name] = summarise(rows)
        print(f"{name}: recall {res[name]['recall']:.3f}, wrong {res[name]['wrong']}, {res[name]['ms']:.1f} ms/image", file=sys.stderr)
    (out / "tags.json").write_text(json.dumps(res, indent=1))
    (out / "tags.md").write_text(table(res, cfg))
    plot(res, out / "tags_recall_offaxis.png")
    return res


def summarise(rows: list) -> dict:
    per_fov, per_bin, per_size, per_cond = {}, {b: [0, 0] for b in BINS}, {z: [0, 0] for z in SIZES}, {}
    det_all = hit_all = wrong = hidden = empty_reports = 0
    errs, ms = [], []
    for lab, s, t, n in rows:
        if lab.get("condition"):  # a row of its own, outside the FoV figures (and the timing)
            c = per_cond.setdefault(lab["condition"], [0, 0, 0, [], 0])
            c[0] += int(s["det"].sum())
            c[1] += int(s["hit"].sum())
            c[2] += s["wrong"]
            c[3] += s["err"]
            c[4] += s["hidden"]
            continue
        ms.append(t)
        if lab["fov"] is None:
            empty_reports += n > 0
            continue
        f = per_fov.setdefault(lab["fov"], [0, 0, 0])
        f[0] += int(s["det"].sum())
        f[1] += int(s["hit"].sum())
        f[2] += s["wrong"]
        wrong += s["wrong"]
        hidden += s["hidden"]
        det_all += int(s["det"].sum())
        hit_all += int(s["hit"].sum())
        errs += s["err"]
        ang = np.array(lab["angle"])
        for b in BINS:
            m = s["det"] & (ang >= b) & (ang < b + 10)
            per_bin[b][0] += int(m.sum())
            per_bin[b][1] += int((s["hit"] & m).sum())
        px = np.array(lab["tag_px"])
        for z, z1 in zip(SIZES, SIZES[1:] + [np.inf]):  # visible corners: tags under the detectable size too
            m = s["vis"] & (px >= z) & (px < z1)
            per_size[z][0] += int(m.sum())
            per_size[z][1] += int((s["found"] & m).sum())
    return {
        "recall": hit_all / max(det_all, 1),
        "wrong": wrong,
        "hidden": hidden,  # reported with their own ids at corners labelled hidden (score_frame): neither hits nor wrong
        "mean_err": float(np.mean(errs)) if errs else float("nan"),
        "median_err": float(np.median(errs)) if errs else float("nan"),
        "empty_reports": empty_reports,
        "ms": statistics.median(ms),
        "fov": {k: {"recall": v[1] / max(v[0], 1), "corners": v[0], "wrong": v[2]} for k, v in sorted(per_fov.items())},
        "bins": {b: {"recall": v[1] / v[0] if v[0] else None, "corners": v[0]} for b, v in per_bin.items()},
        "sizes": {z: {"recall": v[1] / v[0] if v[0] else None, "corners": v[0]} for z, v in per_size.items()},
        "conditions": {
            k: {
                "recall": v[1] / max(v[0], 1),
                "corners": v[0],
                "wrong": v[2],
                "hidden": v[4],
                "mean_err": float(np.mean(v[3])) if v[3] else None,
            }
            for k, v in per_cond.items()
        },
    }


def table(res: dict, cfg: TagEvalConfig) -> str:
    names = list(res)
    lines = [
        f"AprilGrid detection: {cfg.per_fov} frames per FoV at {cfg.width}x{cfg.height}, {cfg.n_empty} without a target, seed {cfg.seed}; "
        f"detectable = visible and the tag >= {cfg.min_tag_px:g} px across; recall within {TOL_PX:g} px with the right id.",
        "",
        f"The set: {describe('aprilgrid', cfg.seed, cfg.width, cfg.height)}.",
        "",
        "| detector | recall | "
        + " | ".join(f"FoV {f}" for f in cfg.fovs)
        + " | wrong | labelled hidden | mean / median err (px) | reports on empty frames | ms / image (median) |",
        "|---" * (7 + len(cfg.fovs)) + "|",
    ]
    for n in names:
        r = res[n]
        fovs = " | ".join(f"{r['fov'].get(f, {}).get('recall', float('nan')):.3f}" for f in cfg.fovs)
        err = f"{r['mean_err']:.3f} / {r['median_err']:.3f}"
        lines.append(
            f"| {n} | {r['recall']:.3f} | {fovs} | {r['wrong']} | {r.get('hidden', 0)} | {err} | {r['empty_reports']} | {r['ms']:.1f} |"
        )
    lines += ["", "Recall per off-axis angle of the corner (deg; corners in the last row):", ""]
    lines.append("| detector | " + " | ".join(f"{b}-{b + 10}" for b in BINS) + " |")
    lines.append("|---" * (1 + len(BINS)) + "|")
    for n in names:
        cells = []
        for b in BINS:
            v = res[n]["bins"][b]
            cells.append("-" if v["recall"] is None else f"{v['recall']:.2f}")
        lines.append(f"| {n} | " + " | ".join(cells) + " |")
    lines.append("| (corners) | " + " | ".join(str(res[names[0]]["bins"][b]["corners"]) for b in BINS) + " |")
    lines += [
        "",
        "Recall per tag size (px across: the smaller singular value of the image of one tag side; corners in the last row; "
        f"tags under {cfg.min_tag_px:g} px are not detectable, their corners are outside the recall above):",
        "",
    ]
    heads = [f"{z}-{z1}" for z, z1 in zip(SIZES, SIZES[1:])] + [f">= {SIZES[-1]}"]
    lines.append("| detector | " + " | ".join(heads) + " |")
    lines.append("|---" * (1 + len(SIZES)) + "|")
    for n in names:
        cells = ["-" if res[n]["sizes"][z]["recall"] is None else f"{res[n]['sizes'][z]['recall']:.2f}" for z in SIZES]
        lines.append(f"| {n} | " + " | ".join(cells) + " |")
    lines.append("| (corners) | " + " | ".join(str(res[names[0]]["sizes"][z]["corners"]) for z in SIZES) + " |")
    conds = [c for c in CONDITIONS if c in res[names[0]].get("conditions", {})]
    if conds:
        lines += [
            "",
            f"Hard frames, {cfg.per_condition} per condition (FoV 180-240; recall / wrong / labelled hidden corners; "
            "corners in the last column):",
            "",
        ]
        lines.append("| condition | " + " | ".join(names) + " | corners |")
        lines.append("|---" * (2 + len(names)) + "|")
        for c in conds:
            cells = [
                f"{res[n]['conditions'][c]['recall']:.3f} / {res[n]['conditions'][c]['wrong']} / {res[n]['conditions'][c].get('hidden', 0)}"
                for n in names
            ]
            lines.append(f"| {c} | " + " | ".join(cells) + f" | {res[names[0]]['conditions'][c]['corners']} |")
    return "\n".join(lines) + "\n"


def plot(res: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4))
    for n, r in res.items():
        xs = [b + 5 for b in BINS if r["bins"][b]["recall"] is not None]
        ys = [r["bins"][b]["recall"] for b in BINS if r["bins"][b]["recall"] is not None]
        ax.plot(xs, ys, marker="o", label=n)
    ax.set_xlabel("off-axis angle of the corner (deg)")
    ax.set_ylabel("recall (right id, within 3 px)")
    ax.set_ylim(0, 1.02)
    ax.grid(alpha=0.3)
    ax.legend()
    ax.set_title("AprilGrid corners found, by off-axis angle (FoV 180-240)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m calib_eval.detection.tags", description=__doc__.splitlines()[0])
    p.add_argument("--per-fov", type=int, default=TagEvalConfig.per_fov)
    p.add_argument("--fov", type=int, nargs="+", default=None)
    p.add_argument("--seed", type=int, default=TagEvalConfig.seed)
    p.add_argument("--per-condition", type=int, default=TagEvalConfig.per_condition, help="frames per hard condition (0: none)")
    p.add_argument("--size", default="1280x720", help="image size WIDTHxHEIGHT (other rigs: 640x480, 848x800, 1920x1080, ...)")
    p.add_argument("--out", default="runs/tags_eval")
    a = p.parse_args(argv)
    try:
        w, h = parse_size(a.size)
    except ValueError as e:
        p.error(str(e))
    cfg = TagEvalConfig(per_fov=a.per_fov, seed=a.seed, per_condition=a.per_condition, width=w, height=h)
    if a.fov:
        cfg.fovs = a.fov
    torch.set_num_threads(2)
    res = evaluate(cfg, Path(a.out))
    print(table(res, cfg))
    return 0


if __name__ == "__main__":
    sys.exit(main())
