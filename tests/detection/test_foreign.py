"""The independent renderer (calib_eval.detection.foreign): its lens laws against known values and
OpenCV, and its labels against the corners in its own frames."""

import cv2
import numpy as np
import pytest

from calib_eval.detection.foreign import BAYER, LENSES, ForeignConfig, camera_isp, main, project, rays, render_frame, room_light


@pytest.mark.parametrize("lens", sorted(LENSES))
def test_lens_laws_round_trip_to_120_degrees(lens):
    """A ray's pixel, cast back, is the same ray, up to 120 deg off the axis (a 240-degree lens)."""
    rng = np.random.default_rng(0)
    theta = rng.uniform(0, np.radians(120), 500)
    phi = rng.uniform(-np.pi, np.pi, 500)
    v = np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], -1)
    centre = np.array([640.0, 360.0])
    q, th = project(v * rng.uniform(0.1, 5.0, (500, 1)), lens, 300.0, centre)
    back, th_back = rays(q, lens, 300.0, centre)
    np.testing.assert_allclose(th, theta, atol=1e-12)
    np.testing.assert_allclose(back, v, atol=1e-9)
    np.testing.assert_allclose(th_back, theta, atol=1e-9)


def test_lens_laws_known_values():
    """At 90 deg off the axis: equidistant f pi / 2, equisolid f sqrt(2), stereographic 2 f."""
    f, centre = 200.0, np.zeros(2)
    side = np.array([1.0, 0.0, 0.0])
    for lens, rho in (("equidistant", f * np.pi / 2), ("equisolid", f * np.sqrt(2)), ("stereographic", 2 * f)):
        q, _ = project(side, lens, f, centre)
        np.testing.assert_allclose(q, [rho, 0.0], atol=1e-9)


def test_equidistant_law_is_opencvs_fisheye_without_distortion():
    """The equidistant law is cv2.fisheye's model with k1..k4 = 0 (points in front of the camera)."""
    rng = np.random.default_rng(1)
    p = np.concatenate([rng.uniform(-2, 2, (200, 2)), rng.uniform(0.2, 3, (200, 1))], 1)
    K = np.array([[310.0, 0, 655.5], [0, 310.0, 351.25], [0, 0, 1]])
    ref = cv2.fisheye.projectPoints(p.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), K, np.zeros(4))[0].reshape(-1, 2)
    q, _ = project(p, "equidistant", 310.0, np.array([655.5, 351.25]))
    np.testing.assert_allclose(q, ref, atol=1e-6)


def test_room_light_falls_across_the_frame_and_casts_a_soft_shadow():
    """The light on a photographed print: 1 at its brightest, down by 20-60 % along one direction,
    and, with a shadow, a step to 0.35-0.7 of it over a few pixels."""
    ys, xs = np.mgrid[0:360, 0:480].astype(np.float64)
    drops, shadows = [], 0
    for i in range(40):
        light = room_light(xs, ys, np.array([240.0, 180.0]), np.random.default_rng(i))
        assert light.shape == (360, 480) and light.max() <= 1.0 and light.min() >= 0.35 * 0.4 - 1e-9
        drops.append(light.min() / light.max())
        dy, dx = np.gradient(light)
        shadows += np.hypot(dx, dy).max() > 0.01  # a shadow's edge: a few % per pixel; the fall alone: ~0.1 % per pixel
    assert 0.14 < min(drops) and max(drops) < 0.85
    assert 10 < shadows < 30  # about half the frames


def _print_spread(fr) -> float:
    """The 10th to 90th percentile of the grey levels inside the hull of a frame's visible corners."""
    inside = np.zeros(fr.image.shape, np.uint8)
    cv2.fillConvexPoly(inside, cv2.convexHull(fr.corners[fr.visible].astype(np.int32)), 1)
    v = fr.image[inside > 0]
    return float(np.percentile(v, 90) - np.percentile(v, 10))


def test_photographed_prints_are_grey_and_their_labels_skip_saturated_corners():
    """``photo``: the print's white is grey (the spread of the board's grey levels well under the
    clean set's in the same scene), JPEG in every frame, and no detectable corner within 2 px of a
    saturated pixel."""
    clean, photo = ForeignConfig(width=480, height=360, min_visible=10), ForeignConfig(width=480, height=360, min_visible=10, photo=True)
    saturated = 0
    for i in range(6):
        fc = render_frame(180, clean, np.random.default_rng([12, i]))
        fp = render_frame(180, photo, np.random.default_rng([12, i]))
        assert fp.jpeg >= 50 and (fc.corners == fp.corners).all()  # the same scene, another print and light
        sat = cv2.dilate((fp.image >= 254).astype(np.uint8), np.ones((5, 5), np.uint8))  # 2 px around saturated pixels
        q = np.clip(np.round(fp.corners).astype(int), 0, [479, 359])
        near = sat[q[:, 1], q[:, 0]] > 0
        assert not (near & fp.detectable).any()
        saturated += (near & fp.visible).any()
        assert _print_spread(fp) < 0.8 * _print_spread(fc)
    assert saturated >= 1  # some frame has visible corners next to saturated pixels (glare, or a bright background)


@pytest.mark.parametrize("layout", sorted(BAYER))
def test_bayer_layouts_are_opencvs(layout):
    """A mosaic with red, green and blue at the sites :data:`BAYER` names for a layout is
    demosaiced by that layout's OpenCV codes (bilinear and edge-aware) to that colour."""
    bilinear, edge_aware, (ry, rx), (by, bx) = BAYER[layout]
    raw = np.full((8, 8), 100, np.uint8)
    raw[ry::2, rx::2], raw[by::2, bx::2] = 200, 50
    for code in (bilinear, edge_aware):
        np.testing.assert_array_equal(cv2.cvtColor(raw, code)[2:6, 2:6], np.broadcast_to([50, 100, 200], (4, 4, 3)))


def test_camera_isp_keeps_flat_grey_and_leaves_halos_at_edges():
    """``isp``: on a step from grey 50 to 200 the processed image undershoots on the dark side and
    overshoots on the bright one (the unsharp mask's halos, at every draw of its settings), while
    away from the edge white balance gives the grey back exactly. A frame is its clean twin
    processed: the same labels and JPEG quality, flat areas within 2 grey levels on median."""
    step = np.full((40, 40), 50, np.uint8)
    step[:, 20:] = 200
    for seed in range(20):
        out = camera_isp(step, np.random.default_rng(seed)).astype(int)
        assert out.shape == (40, 40)
        assert out[:, 12:28].min() < 45 and out[:, 12:28].max() > 205
        assert (out[:, :8] == 50).all() and (out[:, 32:] == 200).all()
    clean, isp = ForeignConfig(width=480, height=360, min_visible=10), ForeignConfig(width=480, height=360, min_visible=10, isp=True)
    for i in range(3):
        fc = render_frame(180, clean, np.random.default_rng([13, i]))
        fi = render_frame(180, isp, np.random.default_rng([13, i]))
        assert fi.jpeg == fc.jpeg and (fi.corners == fc.corners).all() and (fi.detectable == fc.detectable).all()
        a, b = fc.image.astype(np.float32), fi.image.astype(np.float32)
        grad = np.hypot(cv2.Sobel(a, cv2.CV_32F, 1, 0), cv2.Sobel(a, cv2.CV_32F, 0, 1))
        flat = (cv2.dilate(grad, np.ones((7, 7), np.uint8)) < 30) & (a > 20) & (a < 235)
        assert flat.sum() > 10000 and np.median(np.abs(a - b)[flat]) <= 2


def test_labels_sit_on_the_rendered_corners():
    """In frames of the independent renderer (blur, vignetting, noise, sRGB, JPEG), OpenCV's
    cornerSubPix started at each detectable corner's label stays there: the labels are where the
    image has its X-junctions."""
    cfg = ForeignConfig(width=480, height=360, supersample=3, min_visible=10)
    moved = []
    for i in range(3):
        fr = render_frame(180, cfg, np.random.default_rng([11, i]))
        assert fr.image.shape == (360, 480) and fr.image.dtype == np.uint8
        q = fr.corners[fr.detectable].astype(np.float32).reshape(-1, 1, 2)
        crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 0.001)
        r = cv2.cornerSubPix(fr.image, q.copy(), (3, 3), (-1, -1), crit)
        moved.append(np.hypot(*(r - q).reshape(-1, 2).T))
    moved = np.concatenate(moved)
    assert len(moved) >= 30
    assert np.median(moved) < 0.15 and np.percentile(moved, 90) < 0.35


def test_a_defocused_frame_is_its_sharp_twin_blurred_with_its_corners_where_labelled():
    """``defocus``: the same draws (labels, detectable corners, JPEG), a frame with less detail
    (its steepest edges are flatter), and cornerSubPix started at the labels still stays there: a
    Gaussian blur leaves an X-junction where it is."""
    sharp, soft = ForeignConfig(width=480, height=360, min_visible=10), ForeignConfig(width=480, height=360, min_visible=10, defocus=2.5)
    moved = []
    for i in range(3):
        fs = render_frame(180, sharp, np.random.default_rng([17, i]))
        fd = render_frame(180, soft, np.random.default_rng([17, i]))
        assert fd.jpeg == fs.jpeg and (fd.corners == fs.corners).all() and (fd.detectable == fs.detectable).all()
        edge = [np.percentile(np.hypot(cv2.Sobel(f.image, cv2.CV_32F, 1, 0), cv2.Sobel(f.image, cv2.CV_32F, 0, 1)), 99.5) for f in (fs, fd)]
        assert edge[1] < 0.6 * edge[0]  # the steepest edges (the board's) are flatter
        q = fd.corners[fd.detectable].astype(np.float32).reshape(-1, 1, 2)
        crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 0.001)
        r = cv2.cornerSubPix(fd.image, q.copy(), (8, 8), (-1, -1), crit)  # a window a few blurs wide
        moved.append(np.hypot(*(r - q).reshape(-1, 2).T))
    moved = np.concatenate(moved)
    assert len(moved) >= 30 and np.median(moved) < 0.25


@pytest.mark.parametrize("value", ["-1", "25"])
def test_a_defocus_out_of_range_is_one_line_and_exit_2(capsys, tmp_path, value):
    assert main(["--defocus", value, "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error:") and err.count("\n") == 1


def test_bad_frame_count_is_one_line_and_exit_2(capsys, tmp_path):
    assert main(["--per-fov", "0", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error:") and err.count("\n") == 1


def test_aprilgrid_page_decodes_at_kalibrs_corner_positions():
    """The independent AprilGrid page (drawn from OpenCV's marker images, not from our target's
    texture), seen flat from its printed side: cv2.aruco finds all 36 tags, and each tag's four
    corners lie at its Kalibr corners' board coordinates (createGridPoints)."""
    from calib_eval.detection.foreign import aprilgrid_texture, make_board

    board = make_board(ForeignConfig(target="aprilgrid"))
    x0, y0, x1, y1 = board.extent()
    px = 0.0005  # metres per pixel of the view
    ys, xs = np.mgrid[0 : int((y1 - y0) / px), 0 : int((x1 - x0) / px)]
    refl, cover = aprilgrid_texture(board)(x0 + (xs + 0.5) * px, y1 - (ys + 0.5) * px)  # image rows go down the page
    assert cover.all()
    prm = cv2.aruco.DetectorParameters()
    prm.markerBorderBits = 2
    det = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_APRILTAG_36h11), prm)
    corners, ids, _ = det.detectMarkers((refl * 255).astype(np.uint8))
    assert ids is not None and sorted(ids.ravel().tolist()) == list(range(board.n_tags))
    xy = board.board_xy()
    for t, c in zip(ids.ravel(), corners):
        c = c.reshape(4, 2)
        page = np.stack([x0 + (c[:, 0] + 0.5) * px, y1 - (c[:, 1] + 0.5) * px], 1)
        d = np.linalg.norm(page[:, None] - xy[board.tag_corners(t)][None], axis=2)
        assert d.min(1).max() < 0.002  # each decoded corner within 2 mm of its own Kalibr corner (tags are 55 mm)
        assert sorted(d.argmin(1).tolist()) == [0, 1, 2, 3]


@pytest.mark.parametrize("kalibr_yaml", [None, "tagCols: 10\ntagRows: 8\ntagSize: 0.06\ntagSpacing: 0.3\n"])
def test_aprilgrid_frames_show_their_tags_where_labelled(kalibr_yaml, tmp_path):
    """Rendered AprilGrid frames: cv2.aruco decodes tags in them, and the four corners it reports
    for tag t lie at the labels of tag t's four Kalibr corners, one each, far nearer than to any
    other (ids and the board's printed side are right through the lens). The default board, and
    one of a Kalibr target yaml (``--board``: 10 x 8 tags, ids up to 79)."""
    from calib_eval.detection.foreign import make_board

    path = tmp_path / "april.yaml"
    path.write_text("target_type: 'aprilgrid'\n" + (kalibr_yaml or ""))
    cfg = ForeignConfig(target="aprilgrid", width=640, height=480, min_visible=60, board=str(path) if kalibr_yaml else "")
    board = make_board(cfg)
    assert board.n_tags == (80 if kalibr_yaml else 36)
    prm = cv2.aruco.DetectorParameters()
    prm.markerBorderBits = 2
    det = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_APRILTAG_36h11), prm)
    checked, seen_ids = 0, set()
    for i in range(4):
        fr = render_frame(180, cfg, np.random.default_rng([3, i]), board)
        corners, ids, _ = det.detectMarkers(fr.image)
        for t, c in zip([] if ids is None else ids.ravel(), corners):
            assert 0 <= t < board.n_tags
            d = np.linalg.norm(c.reshape(4, 1, 2) - fr.corners[board.tag_corners(t)][None], axis=2)
            assert sorted(d.argmin(1).tolist()) == [0, 1, 2, 3]  # each of its corners nearest one of its own labels
            assert d.min(1).max() < 0.15 * np.sort(d, 1)[:, 1].min()  # aruco's corners are 1-2 px off under the lens
            checked += 1
            seen_ids.add(int(t))
    assert checked >= 5
    if kalibr_yaml:
        assert max(seen_ids) >= 36  # tags beyond the default board's 36


def test_an_output_folder_that_is_a_file_is_one_line_and_exit_1(capsys, tmp_path):
    blocker = tmp_path / "taken"
    blocker.write_text("a file, not a folder")
    assert main(["--per-fov", "1", "--out", str(blocker), "--no-progress"]) == 1
    err = capsys.readouterr().err
    assert err.startswith("error:") and err.count("\n") == 1


def test_a_board_file_of_another_kind_than_the_target_is_one_line_and_exit_1(capsys, tmp_path):
    f = tmp_path / "checker.yaml"
    f.write_text("target_type: 'checkerboard'\ntargetCols: 7\ntargetRows: 5\nrowSpacingMeters: 0.05\ncolSpacingMeters: 0.05\n")
    assert main(["--board", str(f), "--target", "aprilgrid", "--out", str(tmp_path / "out"), "--no-progress"]) == 1
    err = capsys.readouterr().err
    assert err.startswith("error:") and "checkerboard" in err and err.count("\n") == 1
    assert not (tmp_path / "out").exists()  # said before anything is drawn


def test_the_checkerboard_detector_reads_a_grey_print_again_with_its_contrast_raised():
    """A photographed grey print (seed 5, FoV 200, frame 3 of ``--photo``: a 10 x 7 board in the
    shade): read as it is, the frame gives nothing; read again with its contrast raised about the
    local mean (``GridConfig.retry_gain``, the network run again on it), every detectable corner
    with its own id within a pixel of its label (``cotrain detect --grey-print``)."""
    from cotrain.detect.detector import Detector
    from cotrain.detect.grid_config import GridConfig

    fr = render_frame(200, ForeignConfig(target="checkerboard", photo=True), np.random.default_rng([5, 200, 3]))
    assert len(Detector().detect(fr.image).ids) == 0  # the default: read once
    found = Detector(grid=GridConfig(retry_gain=3.0)).detect(fr.image)
    assert fr.visible[found.ids].all() and len(found.ids) >= 0.95 * fr.detectable.sum()
    assert np.linalg.norm(found.xy - fr.corners[found.ids], axis=1).max() < 1.0


def test_cotrain_detect_hints_at_grey_print_and_reads_it(tmp_path, capsys):
    """On images of a photographed grey print that give nothing, ``cotrain detect`` says how many
    gave no corners and names ``--grey-print``; with it the board is found (one process)."""
    import json

    from cotrain.cli import run as cotrain_cli

    fr = render_frame(200, ForeignConfig(target="checkerboard", photo=True), np.random.default_rng([5, 200, 3]))
    cv2.imwrite(str(tmp_path / "grey.png"), fr.image)
    out = tmp_path / "d.json"
    assert cotrain_cli(["detect", str(tmp_path / "grey.png"), "--out", str(out), "--workers", "1"]) == 0
    said = capsys.readouterr().out
    assert "1 of 1 images gave no corners" in said and "--grey-print" in said
    assert cotrain_cli(["detect", str(tmp_path / "grey.png"), "--out", str(out), "--workers", "1", "--grey-print"]) == 0
    assert "--grey-print" not in capsys.readouterr().out
    assert cotrain_cli(["detect", str(tmp_path / "grey.png"), "--out", str(out), "--grey-print", "--slots"]) == 2
    assert "--slots does not run it" in capsys.readouterr().err
    assert len(json.loads(out.read_text())["images"][0]["corners"]) >= 50


def test_the_second_read_reports_only_boards_the_geometry_places(monkeypatch):
    """The checkerboard's second read runs on the raised frame with the network run again, and
    with placements by the network's votes refused (``retry_min_margin``) and the geometry held
    to ``retry_min_geometry_margin``; a frame where the first read finds a board is read once."""
    from cotrain.detect.detector import Detector
    from cotrain.detect.grid_config import GridConfig
    from cotrain.detect.grid_pass import GridResult

    det = Detector(grid=GridConfig(retry_gain=3.0))
    seen = []

    def grid(grey, box, out, cfg, half=True, frame=None, beside=None):
        seen.append((float(grey.std()), cfg.min_margin, cfg.min_geometry_margin))
        return GridResult(np.zeros(0, int), np.zeros((0, 2)), np.zeros(0), 0.0)

    monkeypatch.setattr(det, "_grid", grid)
    rng = np.random.default_rng(0)
    flat = (0.5 + 0.02 * rng.standard_normal((360, 480))).astype(np.float32)
    det.detect(flat)
    assert len(seen) == 2
    (std0, m0, g0), (std1, m1, g1) = seen
    assert (m0, g0) == (det.grid.min_margin, det.grid.min_geometry_margin)
    assert m1 == float("inf") and g1 == 20.0
    assert std1 > 2 * std0  # the second read sees the raised frame

    seen.clear()
    monkeypatch.setattr(det, "_grid", lambda *a, **k: seen.append(1) or GridResult(np.arange(6), np.zeros((6, 2)), np.ones(6), 30.0))
    det.detect(flat)
    assert seen == [1]
