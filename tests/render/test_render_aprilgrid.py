"""The renderer draws Kalibr's AprilGrid with its print toward the camera (Kalibr's page frame: z
toward the viewer): through fisheye cameras, OpenCV's aruco decodes the tags, each at the renderer's
labels of that tag's Kalibr corners."""

import cv2
import numpy as np
import pytest
import torch

from cotrain.geometry import cameras, poses
from cotrain.render.renderer import RenderConfig, Scene, render_scene, sample_draws
from cotrain.targets import TargetConfig, make_target


@pytest.mark.parametrize("model", ["kb4", "ds"])
def test_rendered_aprilgrid_decodes_at_its_labels(model):
    torch.set_num_threads(1)
    g = make_target(TargetConfig(kind="aprilgrid", margin=0.3))
    clean = dict(p_occluder=0.0, p_no_target=0.0, p_motion=0.0, max_blur_sigma=0.3, p_distractor=0.0, p_jpeg=0.0)
    rc = RenderConfig(height=720, width=1280, target=g.cfg, **clean)
    params = cameras.make_camera(model, 200, 1280, 720, 380.0)
    x0, y0, x1, y1 = g.extent()
    c = torch.tensor([(x0 + x1) / 2, (y0 + y1) / 2, 0.0], dtype=torch.float64)
    eye = c + torch.tensor([0.04, -0.03, 0.3], dtype=torch.float64)  # on the printed (+z) side
    T = torch.linalg.inv(poses.look_at(eye, c, torch.tensor([0.0, 1.0, 0.0], dtype=torch.float64)))
    scene = lambda T: Scene([model], [params], torch.tensor([200.0]), torch.tensor([380.0]), T[None])  # noqa: E731
    out = render_scene(rc, g, scene(T), [sample_draws(1, 0)])
    img = (out["image"][0, 0].numpy() * 255).round().astype(np.uint8)
    q, vis = out["corners"][0].numpy(), out["visible"][0].numpy()
    assert vis.all()
    prm = cv2.aruco.DetectorParameters()
    prm.markerBorderBits = 2
    corners, ids, _ = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_APRILTAG_36h11), prm).detectMarkers(img)
    assert ids is not None and len(ids) >= 18 and set(ids.ravel()) <= set(range(36))
    for t, qa in zip(ids.ravel(), corners):
        nearest = np.argmin(np.linalg.norm(qa[0][:, None, :] - q[None], axis=-1), axis=1)  # label nearest each aruco corner
        np.testing.assert_array_equal(nearest, g.tag_corners(t)[[1, 0, 3, 2]])
    # Seen from behind, the print is not drawn and no corner is labelled visible.
    eye_back = c + torch.tensor([0.04, -0.03, -0.3], dtype=torch.float64)
    T_back = torch.linalg.inv(poses.look_at(eye_back, c, torch.tensor([0.0, 1.0, 0.0], dtype=torch.float64)))
    back = render_scene(rc, g, scene(T_back), [sample_draws(1, 0)])
    assert not back["visible"][0].any()
