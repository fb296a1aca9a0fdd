"""One ``Detector(target=...)`` for every target: an AprilGrid and a checkerboard, rendered through
the same 200-degree fisheye camera, are detected through the same class and give the same
``Detection`` type, every reported corner at its own id's exact renderer label."""

import pickle

import cv2
import numpy as np
import pytest
import torch

from cotrain.detect.detector import Detection, Detector, make_detector
from cotrain.detect.grid_config import GridConfig
from cotrain.geometry import cameras, poses
from cotrain.io.detections import detect_files
from cotrain.render.renderer import RenderConfig, Scene, render_scene, sample_draws
from cotrain.targets import TargetConfig, make_target

CLEAN = dict(p_occluder=0.0, p_no_target=0.0, p_motion=0.0, max_blur_sigma=0.3, p_distractor=0.0, p_jpeg=0.0)
SIZE = (1280, 720)


def _view(board, fov: float = 200.0, distance: float = 0.55):
    """A clean rendering of ``board`` seen whole from ``distance`` m in front of its print
    (``Target.front``) through a kb4 camera: uint8 image, labels (N, 2) px, visible (N,)."""
    torch.set_num_threads(1)
    w, h = SIZE
    x0, y0, x1, y1 = board.extent()
    c = [(x0 + x1) / 2, (y0 + y1) / 2, 0.0]
    params = cameras.make_camera("kb4", fov, w, h, 380.0)
    eye, look = torch.tensor([c[0] + 0.03, c[1] - 0.02, board.front * distance], dtype=torch.float64), torch.tensor(c, dtype=torch.float64)
    T = torch.linalg.inv(poses.look_at(eye, look, torch.tensor([0.0, 1.0, 0.0], dtype=torch.float64)))
    scene = Scene(["kb4"], [params], torch.tensor([fov]), torch.tensor([380.0]), T[None])
    out = render_scene(RenderConfig(height=h, width=w, target=board.cfg, **CLEAN), board, scene, [sample_draws(0, 0)])
    img = (out["image"][0, 0].numpy() * 255).round().astype(np.uint8)
    return img, out["corners"][0].numpy(), out["visible"][0].numpy()


@pytest.mark.parametrize("kind", ["aprilgrid", "checkerboard"])
def test_every_target_is_detected_through_the_same_detector(kind, tmp_path):
    board = make_target(TargetConfig(kind=kind, margin=0.3))
    img, labels, visible = _view(board)
    assert visible.sum() >= 0.9 * board.n_corners
    det = Detector(target=board, threads=1)
    found = det.detect(img)
    assert type(found) is Detection
    assert (found.width, found.height) == SIZE
    assert len(found.ids) >= 0.95 * visible.sum(), f"{kind}: {len(found.ids)} of {visible.sum()} visible corners"
    assert visible[found.ids].all()
    err = np.linalg.norm(found.xy - labels[found.ids], axis=1)
    assert err.max() < 0.5, f"{kind}: corner {found.ids[err.argmax()]} is {err.max():.2f} px from its label"
    # detect() reads a checkerboard's black frame while its network runs on a second thread: the
    # same result, to the bit, as the two halves one after the other; and the detector still
    # pickles (cotrain detect's worker processes) after that thread is made.
    halves = det.finish(det.network(img))
    assert np.array_equal(halves.ids, found.ids) and np.array_equal(halves.xy, found.xy)
    assert np.array_equal(pickle.loads(pickle.dumps(det)).detect(img).xy, found.xy)
    # Over files (cotrain detect's path: the next image read and through network() while finish()
    # works on this one), the same corners, to the JSON's rounding.
    cv2.imwrite(str(tmp_path / "view.png"), img)
    (entry,) = detect_files([tmp_path / "view.png"], det, progress=False)["images"]
    assert [c["id"] for c in entry["corners"]] == found.ids.tolist()
    assert np.allclose([[c["x"], c["y"]] for c in entry["corners"]], found.xy, atol=1e-3)


def test_each_target_keys_its_own_cache_and_refuses_what_it_cannot_do():
    grid = make_target(TargetConfig(kind="aprilgrid"))
    checker = make_target(TargetConfig(kind="checkerboard"))
    tags, squares = Detector(target=grid), Detector(target=checker, threads=1)
    assert tags.net is None and tags.path == "tag-pass"  # the tag pass runs no network
    assert "tag_pass" in tags.cache_key() and "grid" in squares.cache_key()
    assert tags.files_per_worker < squares.files_per_worker
    with pytest.raises(ValueError, match="AprilGrid is read by its tags"):
        Detector(target=grid, mode="slots")
    with pytest.raises(ValueError, match="AprilGrid is read by its tags"):
        make_detector(grid, mode="slots")  # cotrain detect --slots
    with pytest.raises(ValueError, match="TagConfig"):
        make_detector(grid, grid=GridConfig(retry_gain=3.0))  # cotrain detect --grey-print
    with pytest.raises(ValueError, match="mode must be"):
        Detector(target=grid, mode="bogus")
    with pytest.raises(ValueError, match="tag pass"):
        tags.grid_result(np.zeros((64, 64), np.float32))
