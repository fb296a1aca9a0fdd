"""Images as the detector takes them: the exposure gain of under-exposed frames."""

import cv2
import numpy as np
import pytest

from cotrain.detect.images import brighten, local_gain
from tests.detect.boards import board_image


def _circle_frame(img: np.ndarray) -> np.ndarray:
    """The image inside a black image circle, as a fisheye frame."""
    h, w = img.shape
    yy, xx = np.mgrid[0:h, 0:w]
    return np.where((xx - w / 2) ** 2 + (yy - h / 2) ** 2 < (0.48 * min(h, w)) ** 2 + (0.3 * w) ** 2, img, 0).astype(np.float32)


def test_a_dark_frame_is_scaled_and_a_normal_one_kept():
    img, _ = board_image(size=(240, 200))
    frame = _circle_frame(img)
    assert brighten(frame) is frame  # bright enough: untouched
    assert brighten((frame * 0.4).astype(np.float32)).max() == np.float32(0.4 * frame.max())  # dim, not dark: untouched
    dark = (frame * 0.2).astype(np.float32)
    out = brighten(dark)
    gain = out[frame > 0.5].mean() / dark[frame > 0.5].mean()
    assert abs(gain - 0.9 / (0.2 * 0.92)) < 0.05  # its whites (0.92 x 0.2) brought to 0.9
    np.testing.assert_allclose(out, np.minimum(dark * gain, 1.0), rtol=1e-5, atol=1e-6)  # one gain: no saddle point moves
    assert (out[frame == 0] == 0).all()  # the black outside the circle stays black
    very_dark = (frame * 0.05).astype(np.float32)
    assert brighten(very_dark).max() <= 6.0 * very_dark.max() + 1e-6  # at most max_gain


def test_a_black_frame_is_left_alone():
    black = np.zeros((120, 160), np.float32)
    assert brighten(black) is black


def test_the_detector_finds_an_under_exposed_board(monkeypatch):
    """A board rendered at a fifth of the normal exposure: found, with right ids, because the
    frame is brightened first (without the gain, without the grid pass's contrast thresholds
    scaled to the board's contrast, and without the second read of a frame where nothing is found
    with its contrast raised, those thresholds refuse it)."""
    import cotrain.detect.detector as detector_mod
    from cotrain.detect.detector import Detector
    from cotrain.render.renderer import RenderConfig, render_batch

    cfg = RenderConfig(height=432, width=768, p_occluder=0.0, p_no_target=0.0, p_jpeg=0.0, p_motion=0.0, p_blur=0.0)
    cfg.exposure_range, cfg.gamma_range, cfg.distance_range, cfg.offaxis_margin_deg = (0.15, 0.15), (1.0, 1.0), (0.2, 0.35), -40.0
    b = render_batch(cfg, [0, 1, 2], seed=8)
    det = Detector(threads=1)
    found = []
    for k in range(3):
        d = det.detect(b["image"][k, 0].numpy())
        err = np.linalg.norm(d.xy - b["corners_raw"][k].numpy()[d.ids], axis=1)
        assert (err < 1.0).all()
        found.append(len(d.ids))
    assert sum(found) >= 0.8 * int(b["visible"].sum())
    from cotrain.detect.grid_config import GridConfig

    monkeypatch.setattr(detector_mod, "brighten", lambda g: g)
    fixed = Detector(threads=1, grid=GridConfig(board_contrast=0.0, retry_gain=0.0))
    assert sum(len(fixed.detect(b["image"][k, 0].numpy()).ids) for k in range(3)) < 0.5 * sum(found)
    # The frame read again with its contrast raised about the local mean finds them too (151 of 162).
    raised = Detector(threads=1, grid=GridConfig(board_contrast=0.0, retry_gain=3.0))  # cotrain detect --grey-print
    dets = [raised.detect(b["image"][k, 0].numpy()) for k in range(3)]
    assert sum(len(d.ids) for d in dets) >= 0.8 * sum(found)
    # Each frame says which look of the schedule found it (cotrain.detect.retries): the raised one where the first finds nothing.
    for k, d in enumerate(dets):
        assert d.look == ("first" if len(fixed.detect(b["image"][k, 0].numpy()).ids) else "contrast raised")


def test_local_gain_stretches_about_the_local_mean():
    """A flat image stays as it is; a faint step far from the frame's edges becomes ``gain`` times
    steeper about its mean, with the step where it was; what would leave [0, 1] is clipped."""
    flat = np.full((60, 80), 0.4, np.float32)
    np.testing.assert_allclose(local_gain(flat, 3.0, 5.0), flat, atol=1e-6)
    step = np.full((60, 200), 0.5, np.float32)
    step[:, 100:] = 0.6
    out = local_gain(step, 3.0, 40.0)
    assert out.dtype == np.float32 and out.shape == step.shape
    across = out[30, 98:102] - out[30, 97:101]
    assert across.argmax() == 2  # the edge between columns 99 and 100, as in the input
    np.testing.assert_allclose(out[30, 100] - out[30, 99], 3 * 0.1, rtol=0.02)  # the mean is smooth across one pixel
    bright = local_gain(np.where(np.arange(80) < 40, 0.1, 0.95).astype(np.float32)[None].repeat(20, 0), 3.0, 10.0)
    assert bright.min() >= 0 and bright.max() <= 1 and bright[10, 45] == 1.0 and bright[10, 35] == 0.0
    with pytest.raises(ValueError, match="sigma"):
        local_gain(flat, 3.0, 0.0)


def test_local_gain_takes_the_mean_at_a_quarter_of_the_resolution_closely():
    """A frame's size and sigma 20 (the fourth look's at 720 px): the mean is taken at a quarter of
    the resolution, and the stretch is within 3 x 0.005 of the one about the full-resolution
    Gaussian mean away from the frame's edges (odd sizes: the quarter is not exact)."""
    rng = np.random.default_rng(1)
    ys, xs = np.mgrid[0:721, 0:1283].astype(np.float32)
    g = (0.5 + 0.2 * np.sin(xs / 37) * np.cos(ys / 53) + 0.05 * rng.standard_normal(xs.shape)).astype(np.float32)
    g = np.clip(g, 0, 1)
    mean = cv2.GaussianBlur(g, (0, 0), 20.0)
    exact = np.clip(mean + 3.0 * (g - mean), 0, 1)
    got = local_gain(g, 3.0, 20.0)
    inner = (slice(60, -60), slice(60, -60))
    assert np.abs(got - exact)[inner].max() < 3 * 0.005
