"""Kalibr's AprilGrid: ids and board coordinates as Kalibr's createGridPoints, the print as Kalibr's
createTargetPDF draws it, and a flat rendering that OpenCV's aruco decodes tag by tag."""

from pathlib import Path

import cv2
import numpy as np
import pytest
import torch
import yaml

from cotrain.targets import AprilGrid, TargetConfig, TargetError, load_target, make_target, target_from_json, target_from_kalibr
from tests.paths import ROOT

# tag36h11 codewords of ids 0 and 1 (AprilTag's family definition): an independent check of the
# codes taken from OpenCV, not a table the implementation uses.
KNOWN_CODES = {0: 0xD5D628584, 1: 0xD97F18B49}
APRILGRID = ROOT / "configs" / "aprilgrid_6x6.yaml"


def test_kalibr_ids_and_coordinates_2x2():
    """Kalibr's source comment for a 2 x 2 grid:
    12-13 14-15 / TAG 2, TAG 3 / 8-9 10-11 // 4-5 6-7 / TAG 0, TAG 1 / 0-1 2-3 (y up)."""
    g = AprilGrid(TargetConfig(kind="aprilgrid", tag_cols=2, tag_rows=2, tag_size=0.1, tag_spacing=0.3))
    assert g.n_corners == 16 and g.symmetries() == ()
    np.testing.assert_array_equal(g.tag_corners([0, 1, 2, 3]), [[0, 1, 5, 4], [2, 3, 7, 6], [8, 9, 13, 12], [10, 11, 15, 14]])
    P = g.points().numpy()
    expect = {0: (0, 0), 1: (0.1, 0), 2: (0.13, 0), 3: (0.23, 0), 4: (0, 0.1), 5: (0.1, 0.1), 8: (0, 0.13), 15: (0.23, 0.23)}
    for i, (x, y) in expect.items():
        np.testing.assert_allclose(P[i], [x, y, 0], atol=1e-12)
    # Kalibr's formula for every point of a 6 x 6 grid.
    g6 = make_target(TargetConfig(kind="aprilgrid"))
    P6 = g6.points().numpy()
    for r in range(12):
        for c in range(12):
            x = (c // 2) * (1 + 0.3) * 0.055 + (c % 2) * 0.055
            y = (r // 2) * (1 + 0.3) * 0.055 + (r % 2) * 0.055
            np.testing.assert_allclose(P6[r * 12 + c], [x, y, 0], atol=1e-12)
    ids = np.arange(144)
    np.testing.assert_array_equal(g6.id_of(g6.ij_of(ids)), ids)


def test_print_matches_kalibrs_drawing():
    """Every cell of tags 0 and 1 as Kalibr's generateAprilTag draws it from the codeword: the
    code matrix (black where a bit is clear, LSB first), turned by np.rot90(.., 2), cell (i, j) at
    (j + 2, 7 - i) cells from the tag's bottom-left corner; the 2-cell border black."""
    g = AprilGrid(TargetConfig(kind="aprilgrid", tag_cols=2, tag_rows=1, tag_size=0.1, tag_spacing=0.3))
    cell = 0.1 / 10
    for t, code in KNOWN_CODES.items():
        m = np.zeros((6, 6))
        for i in range(6):
            for j in range(6):
                if not code & (1 << 6 * i + j):
                    m[i, j] = 1
        m = np.rot90(m, 2)
        black = np.ones((10, 10), bool)  # [x cell, y cell] from the tag's bottom left
        black[2:8, 2:8] = False
        for i in range(6):
            for j in range(6):
                black[j + 2, 7 - i] = bool(m[i, j])
        x0 = t * 0.13
        cx, cy = np.meshgrid(np.arange(10), np.arange(10), indexing="ij")
        xy = torch.from_numpy(np.stack([x0 + (cx + 0.5) * cell, (cy + 0.5) * cell], -1))
        value, cover = g.intensity(xy)
        assert (cover == 1).all()
        np.testing.assert_array_equal(value.numpy() < 0.5, black)
    # Black squares fill the gap crossings around every tag; the gaps between them are white.
    probes = [[-0.015, -0.015], [0.115, 0.115], [0.115, -0.015], [0.115, 0.05], [0.05, -0.015]]
    v, _ = g.intensity(torch.tensor(probes, dtype=torch.float64))
    np.testing.assert_array_equal(v.numpy(), [0, 0, 0, 1, 1])


def _flat_render(g: AprilGrid, ppm: float) -> tuple[np.ndarray, callable]:
    """The sheet seen square-on from the printed side (y up), ``ppm`` pixels per metre; returns
    the image and pixel -> board coordinates."""
    x0, y0, x1, y1 = g.extent()
    W, H = int((x1 - x0) * ppm), int((y1 - y0) * ppm)
    X, Y = np.meshgrid(x0 + (np.arange(W) + 0.5) / ppm, y1 - (np.arange(H) + 0.5) / ppm)
    xy = torch.from_numpy(np.stack([X, Y], -1))
    value, _ = g.intensity(xy, torch.full_like(xy, 1 / ppm))
    to_board = lambda q: np.stack([x0 + (q[..., 0] + 0.5) / ppm, y1 - (q[..., 1] + 0.5) / ppm], -1)  # noqa: E731
    return (value.numpy() * 255).round().astype(np.uint8), to_board


def test_flat_print_decodes_with_opencv_at_kalibrs_positions():
    """cv2.aruco (DICT_APRILTAG_36h11, 2-bit border) decodes every tag of a flat rendering, each
    id where Kalibr puts that tag; aruco's corners (its top left, top right, bottom right, bottom
    left) land on Kalibr's points b + 1, b, b + 2 tag_cols, b + 2 tag_cols + 1."""
    g = make_target(TargetConfig(kind="aprilgrid"))
    ppm = 1500.0
    img, to_board = _flat_render(g, ppm)
    params = cv2.aruco.DetectorParameters()
    params.markerBorderBits = 2
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    corners, ids, _ = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_APRILTAG_36h11), params).detectMarkers(img)
    assert ids is not None and sorted(ids.ravel().tolist()) == list(range(36))
    P = g.points().numpy()[:, :2]
    for t, q in zip(ids.ravel(), corners):
        expected = P[g.tag_corners(t)[[1, 0, 3, 2]]]
        np.testing.assert_allclose(to_board(q[0]), expected, atol=3 / ppm)  # aruco: a few px; other corners: 25 px away


def test_descriptions_round_trip(tmp_path):
    g = load_target(APRILGRID)
    assert isinstance(g, AprilGrid) and (g.tc, g.tr, g.S, g.cfg.tag_spacing) == (6, 6, 0.055, 0.3)
    assert g.to_kalibr() == {"target_type": "aprilgrid", "tagCols": 6, "tagRows": 6, "tagSize": 0.055, "tagSpacing": 0.3}
    assert target_from_kalibr(g.to_kalibr()).to_json() == g.to_json()
    assert target_from_json(g.to_json()).to_kalibr() == g.to_kalibr()
    # Kalibr's own file as it writes it, and bad values, each a one-line error.
    kalibr = {"target_type": "aprilgrid", "tagCols": 4, "tagRows": 3, "tagSize": 0.088, "tagSpacing": 0.3}
    (tmp_path / "t.yaml").write_text(yaml.safe_dump(kalibr))
    assert load_target(tmp_path / "t.yaml").n_corners == 48
    for bad, msg in [
        ({"tagCols": 6, "tagRows": 6, "tagSize": 0.055}, "missing 'tagSpacing'"),
        ({"tagCols": 6, "tagRows": 6, "tagSize": -1, "tagSpacing": 0.3}, "tagSize must be positive"),
        ({"tagCols": 6, "tagRows": 6, "tagSize": 0.05, "tagSpacing": 1.5}, "tag_spacing must be in (0, 1]"),
        ({"tagCols": 30, "tagRows": 30, "tagSize": 0.05, "tagSpacing": 0.3}, "more than tag36h11's 587 codes"),
    ]:
        with pytest.raises(TargetError) as e:
            target_from_kalibr({"target_type": "aprilgrid", **bad})
        assert msg in str(e.value) and "\n" not in str(e.value)


def test_cotrain_detect_runs_the_tag_pass_on_an_aprilgrid(tmp_path):
    """``cotrain detect --target aprilgrid.yaml`` writes the detection JSON with the AprilGrid
    target, Kalibr's ids, and an error entry for an unreadable file (the run goes on)."""
    import json

    from cotrain.cli import run

    g = load_target(APRILGRID)
    img, _ = _flat_render(g, 800.0)
    cv2.imwrite(str(tmp_path / "flat.png"), cv2.GaussianBlur(img, (0, 0), 0.7))
    (tmp_path / "bad.png").write_text("not an image")
    out = tmp_path / "det.json"
    assert run(["detect", "--target", str(APRILGRID), str(tmp_path / "flat.png"), str(tmp_path / "bad.png"), "--out", str(out)]) == 0
    data = json.loads(out.read_text())
    assert data["target"] == g.to_json() and data["model"] == "tag-pass"
    entries = {Path(e["path"]).name: e for e in data["images"]}
    assert entries["bad.png"]["error"] and not entries["bad.png"]["corners"]
    assert sorted(c["id"] for c in entries["flat.png"]["corners"]) == list(range(g.n_corners))


def test_intensity_over_a_footprint_is_the_box_average_of_point_samples():
    """The footprint-averaged print (what the renderer draws) equals the mean of point samples on
    the 4 x 4 sub-pixel grid, for points on the sheet, off it, and with footprints across its
    edge (only points whose footprint reaches the sheet are sampled; the rest are white, uncovered)."""
    g = make_target(TargetConfig(kind="aprilgrid"))
    x0, y0, x1, y1 = g.extent()
    gen = torch.Generator().manual_seed(3)
    xy = torch.rand(4, 300, 2, generator=gen, dtype=torch.float64)
    xy = xy * torch.tensor([x1 - x0 + 0.2, y1 - y0 + 0.2], dtype=torch.float64) + torch.tensor([x0 - 0.1, y0 - 0.1], dtype=torch.float64)
    xy[0, :4] = torch.tensor([[x0 - 0.002, 0.1], [x1 + 0.002, 0.1], [0.1, y0 - 0.0049], [x0 - 0.02, y0 - 0.02]], dtype=torch.float64)
    fp = 0.001 + 0.01 * torch.rand(4, 300, 2, generator=gen, dtype=torch.float64)
    fp[0, :4] = 0.006  # sub-samples reach 2.25 mm to each side: the first two straddle the sheet's edge
    v, cover = g.intensity(xy, fp, samples=4)
    assert v.shape == cover.shape == (4, 300)
    off = (torch.arange(4, dtype=torch.float64) + 0.5) / 4 - 0.5
    v_ref, c_ref = torch.zeros(4, 300, dtype=torch.float64), torch.zeros(4, 300, dtype=torch.float64)
    for ox in off:
        for oy in off:
            p = xy + torch.stack([ox * fp[..., 0], oy * fp[..., 1]], -1)
            vp, cp = g.intensity(p)  # point samples: white off the sheet
            v_ref += vp / 16
            c_ref += cp / 16
    torch.testing.assert_close(v, v_ref)
    torch.testing.assert_close(cover, c_ref)
    assert 0 < float(cover[0, 0]) < 1 and 0 < float(cover[0, 1]) < 1 and float(cover[0, 3]) == 0.0 and float(v[0, 3]) == 1.0
    assert ((cover > 0) & (cover < 1)).any() and (cover == 0).any() and (cover == 1).any()
