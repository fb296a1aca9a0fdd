"""Renderer labels checked against the pixels, independently of the renderer's own math."""

import math

import cv2
import numpy as np
import pytest
import torch

from cotrain.geometry import cameras, poses
from cotrain.render.renderer import RenderConfig, render_batch
from cotrain.targets import Checkerboard

CLEAN = dict(p_blur=0.0, p_motion=0.0, noise_range=(0.0, 0.0), p_jpeg=0.0, p_occluder=0.0, p_distractor=0.0)


@pytest.fixture(scope="module")
def clean_batch():
    cfg = RenderConfig(height=432, width=768, **CLEAN)
    return cfg, render_batch(cfg, list(range(24)), seed=3)


def test_labels_match_cornersubpix(clean_batch):
    cfg, out = clean_batch
    errs = []
    for b in range(out["image"].shape[0]):
        img = out["image"][b, 0].numpy().astype(np.float32)
        q = out["corners_raw"][b].numpy()
        sel = out["visible"][b].numpy() & (out["square_px"][b].numpy() > 10)
        # Well inside the frame and the image circle, so the refinement window sees only the board.
        p = out["params"][b]
        m = cameras.get_model(["kb4", "ucm", "eucm", "ds"][int(out["model_index"][b])])
        c = np.array([p[m.index("cx")].item(), p[m.index("cy")].item()])
        sel &= (q[:, 0] > 10) & (q[:, 0] < cfg.width - 11) & (q[:, 1] > 10) & (q[:, 1] < cfg.height - 11)
        # The refinement window (9 x 9) lies on the checker squares only (no board outline in it).
        full = torch.nn.functional.max_pool2d(1 - out["board_mask"][b : b + 1], 9, 1, 4)[0, 0] < 0.02
        qi = np.clip(np.round(q).astype(int), 0, [cfg.width - 1, cfg.height - 1])
        sel &= full.numpy()[qi[:, 1], qi[:, 0]]
        if not sel.any():
            continue
        start = (q[sel] + np.array([0.7, -0.7])).astype(np.float32).reshape(-1, 1, 2)  # 1 px away
        ref = cv2.cornerSubPix(img, start, (4, 4), (-1, -1), (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 100, 1e-5))
        errs.append(np.linalg.norm(ref.reshape(-1, 2) - q[sel], axis=1))
        assert np.isfinite(c).all()
    e = np.concatenate(errs)
    assert len(e) > 200
    # cornerSubPix assumes straight edges; fisheye edges curve, which costs it a few hundredths.
    assert np.median(e) < 0.08
    assert np.mean(e < 0.1) > 0.85
    assert np.percentile(e, 99) < 0.3


def test_ids_follow_conventions(clean_batch):
    """The square touching corner 0 towards the board origin is black, its neighbours white."""
    cfg, out = clean_batch
    board = Checkerboard(cfg.target)
    s = board.s
    checked = 0
    for b in range(out["image"].shape[0]):
        if not (out["visible"][b, 0] and out["visible"][b, 1] and out["visible"][b, 9] and out["square_px"][b, 0] > 12):
            continue
        model = ["kb4", "ucm", "eucm", "ds"][int(out["model_index"][b])]
        pts = torch.tensor(
            [[0.5 * s, 0.5 * s, 0], [1.5 * s, 0.5 * s, 0], [0.5 * s, 1.5 * s, 0], [1.5 * s, 1.5 * s, 0]], dtype=torch.float64
        )
        q, ok = cameras.project(model, poses.transform_points(out["T_cam_board"][b], pts), out["params"][b])
        img = out["image"][b, 0]
        vals = [img[int(round(y)), int(round(x))].item() for x, y in q.tolist()]
        assert vals[0] < vals[1] and vals[0] < vals[2] and vals[3] < vals[1]
        checked += 1
    assert checked >= 2


def test_narrow_fov_matches_opencv_fisheye():
    cfg = RenderConfig(height=480, width=640, models=["kb4"], model_weights=[1.0], fov_range=(150, 160), **CLEAN)
    out = render_batch(cfg, list(range(6)), seed=11)
    board = Checkerboard(cfg.target)
    P = board.points().numpy()
    n = 0
    for b in range(6):
        T = out["T_cam_board"][b].numpy()
        pc = P @ T[:3, :3].T + T[:3, 3]
        front = pc[:, 2] > 0.05
        if not front.any():
            continue
        fx, fy, cx, cy, k1, k2, k3, k4 = out["params"][b].tolist()
        K = np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1.0]])
        rvec, _ = cv2.Rodrigues(T[:3, :3])
        tvec = np.ascontiguousarray(T[:3, 3]).reshape(3, 1)
        q_cv, _ = cv2.fisheye.projectPoints(np.ascontiguousarray(P[front]).reshape(-1, 1, 3), rvec, tvec, K, np.array([k1, k2, k3, k4]))
        np.testing.assert_allclose(out["corners_raw"][b].numpy()[front], q_cv.reshape(-1, 2), atol=2e-3)
        n += front.sum()
    assert n > 50


def test_invisible_outside_circle_and_behind():
    cfg = RenderConfig(**CLEAN)
    out = render_batch(cfg, list(range(32)), seed=5)
    vis = out["visible"]
    assert vis.any()
    for b in range(32):
        model = ["kb4", "ucm", "eucm", "ds"][int(out["model_index"][b])]
        m = cameras.get_model(model)
        p = out["params"][b]
        pc = poses.transform_points(out["T_cam_board"][b], Checkerboard().points())
        theta = cameras.off_axis_angle(pc)
        fov = out["fov"][b].item()
        assert not bool((vis[b] & (theta > math.radians(fov) / 2)).any())
        q = out["corners_raw"][b]
        r = (q - torch.stack([p[m.index("cx")], p[m.index("cy")]]).float()).norm(dim=-1)
        radius = out["radius"][b].item()  # the image-circle radius the camera was built with
        assert not bool((vis[b] & (r > radius)).any())
    # A board behind the camera: nothing visible.
    T = poses.make_pose(torch.eye(3, dtype=torch.float64), torch.tensor([-0.2, -0.14, -0.5], dtype=torch.float64))
    from cotrain.render.renderer import Scene, corner_labels

    scene = Scene(["kb4"], [cameras.make_camera("kb4", 180, 384, 216)], torch.tensor([180.0]), torch.tensor([108.0]), T[None])
    assert not bool(corner_labels(cfg, Checkerboard(), scene)["visible"].any())


def test_reproducible_per_sample():
    """Sample i of a stream, in any batch (in a render worker too: tests/model/test_training.py)."""
    cfg = RenderConfig(height=96, width=160)
    a = render_batch(cfg, [3, 5], seed=9)
    b = render_batch(cfg, [5], seed=9)
    # Batched kernels may differ in the last float bit; labels are exact.
    assert torch.allclose(a["image"][1], b["image"][0], atol=1e-5) and torch.equal(a["corners"][1], b["corners"][0])


def test_a_batch_renders_each_sample_as_it_renders_alone():
    """The batched paths (rays unprojected per camera family, backgrounds painted for the whole
    batch) give every sample what it gets alone: its draws come from its own generator, and the
    batch only groups the arithmetic. Every family, distractors and occluders in every sample."""
    cfg = RenderConfig(height=72, width=120, p_distractor=1.0, p_occluder=1.0)
    idx = list(range(12))
    batch = render_batch(cfg, idx, seed=4)
    assert len({cfg.models[int(m)] for m in batch["model_index"]}) >= 3
    for i in idx:
        alone = render_batch(cfg, [i], seed=4)
        assert torch.allclose(batch["image"][i], alone["image"][0], atol=1e-5)
        assert torch.equal(batch["corners_raw"][i], alone["corners_raw"][0]) and torch.equal(batch["visible"][i], alone["visible"][0])


def test_preview_cli(tmp_path):
    from cotrain.cli import run

    out = tmp_path / "p.png"
    assert run(["render-preview", "--n", "4", "--out", str(out), "height=96", "width=160"]) == 0
    img = cv2.imread(str(out))
    assert img is not None and img.shape == (192, 320, 3)


def test_appearance_ranges_reach_the_image():
    """The appearance fields the evaluation's hard conditions set: an over-exposed frame clips its
    whites, a dull print has less contrast between its squares, strong vignetting darkens the
    rim against the centre, a longer motion blur leaves weaker gradients. The defaults draw the
    same frames as before the fields existed (same seed, same image)."""
    import dataclasses

    base = RenderConfig(
        height=120, width=200, p_occluder=0.0, p_blur=0.0, p_motion=0.0, p_jpeg=0.0, noise_range=(0.0, 0.0), p_no_target=0.0
    )
    ids, seed = [0, 1, 2], 11

    def render(**kw):
        return render_batch(dataclasses.replace(base, **kw), ids, seed)

    ref = render()
    defaults = dict(exposure_range=(0.6, 1.4), gamma_range=(0.7, 1.4), black_range=(0.02, 0.2), white_range=(0.6, 1.0))
    assert torch.equal(
        render(**defaults, vignette_range=(0.0, 0.6), motion_kernel=(5, 5), motion_direction=(-1.0, 1.0), offaxis_min_deg=0.0)["image"],
        ref["image"],
    )
    bright = render(exposure_range=(2.5, 2.5), gamma_range=(1.0, 1.0))["image"]
    assert (bright >= 0.999).float().mean() > 5 * (ref["image"] >= 0.999).float().mean() + 0.01

    def square_contrast(b):
        on = b["image"][b["board_mask"] > 0.5]
        return float(on.quantile(0.9) - on.quantile(0.1))

    dull = render(black_range=(0.35, 0.35), white_range=(0.55, 0.55))
    assert square_contrast(dull) < 0.6 * square_contrast(ref)
    flat = dict(vignette_range=(0.0, 0.0), p_no_target=1.0)
    even, dark = render(**flat), render(**{**flat, "vignette_range": (0.9, 0.9)})
    ratio = dark["image"] / even["image"].clamp_min(1e-3)
    centre = ratio[..., 50:70, 90:110].median()
    assert float(centre) > 0.85 and float(ratio[..., 60, 5:20].median()) < 0.6 * float(centre)
    short, long = render(p_motion=1.0, motion_kernel=(3, 3)), render(p_motion=1.0, motion_kernel=(15, 15))

    def grad(x):
        return float((x[..., 1:, :] - x[..., :-1, :]).abs().mean() + (x[..., :, 1:] - x[..., :, :-1]).abs().mean())

    assert grad(long["image"]) < 0.8 * grad(short["image"])


def test_boards_drawn_off_axis_at_least_offaxis_min():
    """offaxis_min_deg puts the board at the rim: its centre lies farther off-axis."""
    import dataclasses

    base = RenderConfig(height=120, width=200, fov_range=(200.0, 200.0), models=["kb4"], model_weights=[1.0], p_no_target=0.0)
    x0, y0, x1, y1 = Checkerboard().extent()
    centre = torch.tensor([(x0 + x1) / 2, (y0 + y1) / 2, 0.0, 1.0], dtype=torch.float64)

    def offaxis_deg(cfg):
        T = render_batch(cfg, list(range(16)), 5)["T_cam_board"].double()
        p = (T @ centre)[:, :3]
        return torch.rad2deg(torch.atan2(p[:, :2].norm(dim=-1), p[:, 2]))

    near, rim = offaxis_deg(base), offaxis_deg(dataclasses.replace(base, offaxis_min_deg=80.0))
    # The board's centre is jittered off the drawn ray by up to 0.3 board sizes.
    assert float(rim.median()) > float(near.median()) + 15 and float(rim.min()) > 50


def test_labels_follow_one_sided_motion_blur():
    """Motion blur that weights one end of the exposure more (kornia's ``direction``) moves the
    whole image toward that end, by up to (length + 1) / 6 px; the labels move with it
    (:func:`motion_blur_shift`), so cornerSubPix lands on them as in frames blurred evenly. Known
    values: the shift of a 5 px blur with direction 1 along x is +1 px (kornia filters by correlation;
    the saddles of a blurred board move 1.017 px there, so labels stay within a few hundredths)."""
    from cotrain.render.renderer import motion_blur_shift

    np.testing.assert_allclose(motion_blur_shift(5, 0.0, 1.0).numpy(), [1.0, 0.0], atol=1e-5)
    np.testing.assert_allclose(motion_blur_shift(5, 90.0, -1.0).numpy(), [0.0, 1.0], atol=1e-5)
    np.testing.assert_allclose(motion_blur_shift(9, 37.0, 0.0).numpy(), [0.0, 0.0], atol=1e-5)

    def offsets(direction: float) -> tuple[np.ndarray, np.ndarray]:
        blur = {"p_motion": 1.0, "motion_kernel": (5, 5), "motion_direction": (direction, direction)}
        cfg = RenderConfig(height=432, width=768, **{**CLEAN, **blur})
        out = render_batch(cfg, list(range(6)), seed=5)
        means = []
        for b in range(6):
            img = out["image"][b, 0].numpy().astype(np.float32)
            q = out["corners_raw"][b].numpy()
            sel = out["visible"][b].numpy() & (out["square_px"][b].numpy() > 14)
            sel &= (q[:, 0] > 12) & (q[:, 0] < cfg.width - 13) & (q[:, 1] > 12) & (q[:, 1] < cfg.height - 13)
            full = torch.nn.functional.max_pool2d(1 - out["board_mask"][b : b + 1], 11, 1, 5)[0, 0] < 0.02
            qi = np.clip(np.round(q).astype(int), 0, [cfg.width - 1, cfg.height - 1])
            sel &= full.numpy()[qi[:, 1], qi[:, 0]]
            if sel.sum() < 4:
                continue
            start = q[sel].astype(np.float32).reshape(-1, 1, 2)
            ref = cv2.cornerSubPix(img, start, (5, 5), (-1, -1), (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 100, 1e-5))
            means.append((ref.reshape(-1, 2) - q[sel]).mean(0))
        return np.array(means), out["image"]

    one_sided, img1 = offsets(1.0)
    even, img0 = offsets(0.0)
    assert len(one_sided) >= 3 and len(even) >= 3
    # The corners' images sit on their labels (no common shift left), one-sided or not ...
    assert np.abs(one_sided).max() < 0.25 and np.abs(even).max() < 0.25
    # ... although the one-sided blur moved the images by a px (the same scenes, blurred otherwise).
    assert float((img1 - img0).abs().max()) > 0.2


def test_glare_fades_the_print_under_a_spot_and_nowhere_else():
    """Glare (``p_glare``) adds light to the print only: it lifts the board's pixels (most where
    they clip), changes nothing in a frame without the board, and moves no corner; corners it
    washes out (contrast under 2 % after exposure and clipping) are not visible. With ``p_glare`` 0
    nothing is drawn (frames are those of before the field existed:
    test_appearance_ranges_reach_the_image)."""
    import dataclasses

    base = RenderConfig(height=180, width=320, p_occluder=0.0, p_jpeg=0.0, noise_range=(0.0, 0.0), p_no_target=0.0, p_distractor=0.0)
    spot = dict(p_glare=1.0, glare_strength=(1.5, 1.5), glare_size=(0.3, 0.3))
    ids, seed = list(range(8)), 21
    plain = render_batch(base, ids, seed)
    glare = render_batch(dataclasses.replace(base, **spot), ids, seed)
    assert torch.equal(glare["corners_raw"], plain["corners_raw"]) and torch.equal(glare["board_mask"], plain["board_mask"])
    diff = glare["image"] - plain["image"]
    assert float(diff.min()) > -1e-6  # light is only added
    assert float(diff[plain["board_mask"] > 0.99].mean()) > 0.05
    assert bool((glare["visible"] <= plain["visible"]).all()) and int(glare["visible"].sum()) < int(plain["visible"].sum())
    # Drawn in some samples only: those without a spot render, and are labelled, as without glare.
    some = render_batch(dataclasses.replace(base, **{**spot, "p_glare": 0.5}), ids, seed)
    alike = [i for i in range(len(ids)) if torch.equal(some["image"][i], plain["image"][i])]
    assert 0 < len(alike) < len(ids)
    assert all(torch.equal(some["visible"][i], plain["visible"][i]) for i in alike)
    empty = dict(p_no_target=1.0)
    assert torch.equal(
        render_batch(dataclasses.replace(base, **empty, **spot), ids, seed)["image"],
        render_batch(dataclasses.replace(base, **empty), ids, seed)["image"],
    )
