"""The rough FoV the calibrator starts from, estimated where the user does not give ``--fov``.

A user rarely knows the FoV of a lens to a degree, and the calibrator only needs it to seed the
focal length (its focal search then scales the seed from 0.4 to 2.5 times). Here each camera's
seed comes from a generic guess (:data:`GUESS_FOV_DEG`), scaled by the same focal search over the
camera's first views; the FoV is then the angle the scaled model sees across the image circle
(the circle touching the shorter image side, the meaning ``--fov`` has everywhere).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from calib_eval.calibration.initialisation import focal_search, initial_guess
from cotrain.geometry import cameras
from cotrain.io.sequence import Sequence

GUESS_FOV_DEG = 180.0  # the seed of the search (deg); the search scales its focal length 0.4 to 2.5 times


@dataclass
class FovEstimate:
    """The FoV used, and how it was found."""

    fov_deg: float  # the value the calibrator starts from (deg): the median over the cameras
    per_camera_deg: list[float | None]  # each camera's estimate (deg); None for a camera without views

    def line(self, names: list[str]) -> str:
        each = ", ".join(f"{n} {f:.0f}" for n, f in zip(names, self.per_camera_deg) if f is not None)
        return f"no --fov given: estimated {self.fov_deg:.0f} deg ({each}) by a focal search over each camera's first views"


def camera_fov(model: str, intr, width: int, height: int) -> float | None:
    """FoV (deg) of camera ``intr`` across the image circle of a ``width`` x ``height`` image:
    twice the off-axis angle of the pixel ``min(width, height) / 2`` right of the principal
    point; None where the model cannot unproject it."""
    m = cameras.get_model(model)
    cx, cy = float(intr[m.index("cx")]), float(intr[m.index("cy")])
    q = np.array([[cx + min(width, height) / 2.0, cy]])
    v, ok = cameras.unproject(model, q, np.asarray(intr, dtype=np.float64))
    if not bool(ok[0]):
        return None
    return 2.0 * math.degrees(math.acos(float(np.clip(float(v[0, 2]), -1.0, 1.0))))


def estimate_fov(seq: Sequence, models: list[str]) -> FovEstimate:
    """A rough FoV per camera of ``seq`` (``models[c]`` its family) and their median."""
    per_camera: list[float | None] = []
    for c, info in enumerate(seq.cameras):
        obs = seq.by_camera(c)
        if not obs:
            per_camera.append(None)
            continue
        guess = initial_guess(models[c], GUESS_FOV_DEG, info.width, info.height)
        fov = camera_fov(models[c], focal_search(models[c], guess, obs, seq.target), info.width, info.height)
        # The searched model cannot see the circle's rim (a focal length too short for the family's
        # domain): keep the seed, from which the calibrator searches again.
        per_camera.append(GUESS_FOV_DEG if fov is None else fov)
    found = [f for f in per_camera if f is not None]
    if not found:
        raise ValueError("no camera sees the board in any view, so no FoV can be estimated; give --fov DEGREES")
    return FovEstimate(float(np.median(found)), per_camera)
