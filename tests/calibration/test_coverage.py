"""Capture guidance from coverage: what is missing, said so a person can act on it."""

import numpy as np

from calib_eval.benchmark.rigs import SynthSpec, make_sequence, paper_config
from calib_eval.calibration.coverage import coverage
from calib_eval.cli import run as calib_cli
from cotrain.io.sequence import Observation, write_sequence


def _restricted(seq, keep):
    """The sequence with only the corners ``keep(cam, q) -> (M,) bool`` accepts."""
    out = []
    for o in seq.observations:
        k = keep(o.cam, o.q)
        if k.sum() >= 6:
            out.append(Observation(o.cam, o.view, o.ids[k], o.q[k], o.weight[k], o.frame))
    seq.observations = out
    return seq


def test_centre_only_camera_is_told_to_reach_the_rim(tmp_path, capsys):
    seq, _ = make_sequence(paper_config("FoV220_90"), SynthSpec(n_frames=120), seed=2)
    centre = np.array([639.5, 359.5])
    seq = _restricted(seq, lambda cam, q: (np.linalg.norm(q - centre, axis=1) < 0.6 * 360) | (cam == 0))
    cov = coverage(seq)
    cam1 = cov.cameras[1]
    assert cam1.max_radius < 0.6 and cov.cameras[0].max_radius > 0.95
    assert any(a.startswith("cam1: no observation beyond 0.") and "near the rim" in a for a in cov.advice)
    assert not any(a.startswith("cam0: no observation beyond") for a in cov.advice)
    # The command prints the same sentences.
    root = write_sequence(seq, tmp_path / "seq")
    assert calib_cli(["coverage", str(root)]) == 0
    assert "cam1: no observation beyond" in capsys.readouterr().out


def test_missing_sector_and_unlinked_cameras():
    seq, _ = make_sequence(paper_config("FoV220_90"), SynthSpec(n_frames=120), seed=2)
    centre = np.array([639.5, 359.5])
    seq = _restricted(seq, lambda cam, q: ~((cam == 0) & (q[:, 0] > centre[0] + 200)))  # cam0: nothing far right
    cov = coverage(seq)
    assert any(a.startswith("cam0: few corners near the rim at the") and "right" in a for a in cov.advice)
    # Keep only a handful of views both cameras see: the extrinsics are under-determined.
    shared = sorted(v for v, obs in seq.by_view().items() if len(obs) == 2)
    drop = set(shared[3:])
    seq.observations = [o for o in seq.observations if not (o.cam == 1 and o.view in drop)]
    cov = coverage(seq)
    assert cov.shared_views[(0, 1)] == 3
    assert any("cam0 and cam1: only 3 views where both see the board" in a for a in cov.advice)


def test_cropped_rim_is_not_asked_for_and_a_stray_corner_does_not_grow_the_circle():
    """A circle much larger than the sensor's height: its top and bottom rim are off the sensor, so
    no advice asks for corners there; one stray corner far out does not move R."""
    seq, _ = make_sequence(paper_config("FoV220_90"), SynthSpec(n_frames=120), seed=2)
    for cam in seq.cameras:
        cam.mask_radius = 640.0
    cov = coverage(seq)
    cam0 = cov.cameras[0]
    assert cam0.R == 640.0
    assert not cam0.reachable[2] and not cam0.reachable[6]  # bottom and top: off the sensor
    assert cam0.reachable[0] and cam0.reachable[4]  # right and left: on it
    assert not any(("top" in a or "bottom" in a) and "near the rim" in a for a in cov.advice)
    # A stray corner 2000 px out.
    seq2, _ = make_sequence(paper_config("FoV220_90"), SynthSpec(n_frames=120), seed=2)
    before = coverage(seq2).cameras[0]
    o = seq2.by_camera(0)[0]
    o.q = o.q.copy()
    o.q[0] = [2600.0, 359.5]
    after = coverage(seq2).cameras[0]
    assert abs(after.R - before.R) < 1.0 and after.max_radius <= 1.0  # (the 99.5th percentile moves by one corner)


def test_narrow_views_are_told_to_span_the_radius(capsys, tmp_path):
    """Every view confined to a thin ring of the image: the advice asks for views reaching from the
    middle toward the rim, which anchor the intrinsic initialisation."""
    seq, _ = make_sequence(paper_config("FoV220_90"), SynthSpec(n_frames=160), seed=2)
    centre = np.array([639.5, 359.5])
    ring = lambda cam, q: (cam == 1) | (np.abs(np.linalg.norm(q - centre, axis=1) - 250) < 40)  # noqa: E731
    seq = _restricted(seq, ring)
    cov = coverage(seq)
    assert cov.cameras[1].widest_view > 0.5 and cov.cameras[0].widest_view < 0.3
    assert any(a.startswith("cam0: no single view spans more than 0.") for a in cov.advice)
    assert not any(a.startswith("cam1: no single view spans") for a in cov.advice)


def test_anchor_radial_span_in_the_report(tmp_path):
    """The report shows, per camera, the selector's anchors and the radial span they cover."""
    from calib_eval.calibration.calibrator import CalibConfig, calibrate
    from calib_eval.calibration.report_html import anchor_spans, write_report_html
    from calib_eval.calibration.selector import SelectorConfig, select

    seq, _ = make_sequence(paper_config("FoV200_60"), SynthSpec(n_frames=80), seed=4)
    sel = select(seq, SelectorConfig(fov=200))
    anchors = {c: [s.view for s in sel.scores if s.cam == c and s.stage == "anchor"] for c in range(2)}
    spans = anchor_spans(seq, anchors)
    cov = coverage(seq)
    for c in range(2):
        n, lo, hi = spans[c]
        assert n == len(anchors[c]) > 0 and 0.0 <= lo < hi <= 1.05  # R is the 99.5th percentile radius
        r = np.concatenate([cov.cameras[c].radius_of(o.q) for o in seq.by_camera(c) if o.view in anchors[c]])
        assert lo == r.min() and hi == r.max()
    sub = seq.subset(sel.keep)
    page = write_report_html(calibrate(sub, CalibConfig(model="kb4", fov=200), sel.order), sub, tmp_path, anchors).read_text()
    n, lo, hi = anchor_spans(sub, anchors)[0]  # the page's sequence is the selection
    assert f"<td>{n}, {lo:.2f} - {hi:.2f}</td>" in page and "nan" not in page
