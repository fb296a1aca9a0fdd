"""What a recording shows of each camera's image circle, and what to capture next.

``calib-eval coverage SEQ`` (or ``--bag REC --topics ...``) prints, per camera, how far out the
board was seen (as a fraction of the image radius R about the image centre), which parts of the
circle hold no corners, and whether the cameras share enough views for their extrinsics, each as a
sentence a person can act on. The image circle is split into 3 rings (0-0.4, 0.4-0.8, 0.8-1 of
R) and 8 sectors (compass directions in the image: up is "top"). A sector whose rim lies mostly
outside the sensor (a circle cropped by the image's top and bottom) is not asked for. The radial
span of single views matters too: intrinsic initialisation wants views whose corners reach from
the middle toward the rim (the selector's anchors).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from calib_eval.calibration.selector import usable_radius
from cotrain.io.sequence import Sequence

RINGS = (0.0, 0.4, 0.8, 1.0)  # ring edges, fractions of R
SECTORS = ("right", "lower right", "bottom", "lower left", "left", "upper left", "top", "upper right")  # image y points down


@dataclass
class CameraCoverage:
    name: str
    views: int  # observations (views with corners) of this camera
    corners: int
    max_radius: float  # largest corner radius / R (the 99.5th percentile: a stray corner does not count)
    cells: np.ndarray  # (rings, sectors) corner counts
    centre: np.ndarray  # (2,) image centre, px
    R: float  # image radius, px: the usable radius, or farther where most corners prove a larger circle
    widest_view: float  # largest radial span (highest - lowest corner radius, of R) of a single view
    reachable: np.ndarray  # (sectors,) bool: at least a fifth of the sector's rim ring lies on the sensor
    advice: list[str] = field(default_factory=list)
    placement: list[str] = field(default_factory=list)  # the advice that is only where to hold the board (rim sectors,
    # the middle): its effect on the result is the projection uncertainty, so the verdict does not name it as a cause

    def radius_of(self, q: np.ndarray) -> np.ndarray:
        """Radii (M,) of pixels (M, 2) as fractions of R."""
        return np.linalg.norm(q - self.centre, axis=-1) / self.R


@dataclass
class Coverage:
    cameras: list[CameraCoverage]
    shared_views: dict[tuple[int, int], int]  # (cam a, cam b) -> views both saw
    advice: list[str]  # every sentence, cameras first, then pairs


def coverage(
    seq: Sequence, min_cell: int = 20, min_shared: int = 10, rim: float = 0.8, min_views: int = 4, min_span: float = 0.4
) -> Coverage:
    """Coverage of ``seq`` per camera and per camera pair, with capture advice. A cell of the
    image circle counts as covered with ``min_cell`` corners; extrinsics want ``min_shared``
    views seen by both cameras; "near the rim" is beyond ``rim`` of R; a camera needs ``min_views``
    views (the calibrator's minimum) and one view spanning ``min_span`` of R radially."""
    cams = []
    for c, info in enumerate(seq.cameras):
        obs = seq.by_camera(c)
        R = usable_radius(info.width, info.height, info.mask_radius)
        centre = np.array([(info.width - 1) / 2, (info.height - 1) / 2])
        q = np.concatenate([o.q for o in obs]) if obs else np.zeros((0, 2))
        d = q - centre
        dist = np.linalg.norm(d, axis=1)
        far = float(np.percentile(dist, 99.5)) if len(dist) else 0.0
        R = max(R, far)  # most corners seen farther out prove a larger circle; one stray corner does not
        r = dist / R
        ring = np.clip(np.searchsorted(RINGS, r, side="right") - 1, 0, len(RINGS) - 2)
        sector = (np.floor((np.arctan2(d[:, 1], d[:, 0]) % (2 * math.pi)) / (2 * math.pi / len(SECTORS)) + 0.5) % len(SECTORS)).astype(int)
        cells = np.zeros((len(RINGS) - 1, len(SECTORS)), int)
        np.add.at(cells, (ring, sector), 1)
        spans = [float(np.ptp(np.linalg.norm(o.q - centre, axis=1))) / R for o in obs if len(o.q)]
        reachable = _rim_on_sensor(centre, R, info.width, info.height, RINGS[-2])
        cc = CameraCoverage(info.name, len(obs), len(q), far / R, cells, centre, R, max(spans, default=0.0), reachable)
        if len(obs) < min_views:
            cc.advice.append(
                f"{info.name}: only {len(obs)} views with the board; the calibration needs at least {min_views}, add 20 or more"
            )
        elif cc.max_radius < rim:
            cc.advice.append(
                f"{info.name}: no observation beyond {cc.max_radius:.2f} of the image radius; add views with the board near the rim"
            )
        missing = [SECTORS[s] for s in range(len(SECTORS)) if cells[-1, s] < min_cell and reachable[s]]
        if len(obs) >= min_views and cc.max_radius >= rim and missing:
            cc.advice.append(f"{info.name}: few corners near the rim at the {_join(missing)} of the image circle; hold the board there")
            cc.placement.append(cc.advice[-1])
        inner = [SECTORS[s] for s in range(len(SECTORS)) if cells[:2, s].sum() < min_cell]
        if len(obs) >= min_views and len(inner) > len(SECTORS) // 2:
            cc.advice.append(
                f"{info.name}: the middle of the image is thinly covered ({_join(inner)}); add views with the board closer to the centre"
            )
            cc.placement.append(cc.advice[-1])
        if len(obs) >= min_views and cc.widest_view < min_span:
            cc.advice.append(
                f"{info.name}: no single view spans more than {cc.widest_view:.2f} of the image radius; add views where the board "
                "reaches from near the centre toward the rim (they anchor the focal length against the distortion)"
            )
        cams.append(cc)
    shared: dict[tuple[int, int], int] = {}
    by_view = seq.by_view()
    for a in range(len(seq.cameras)):
        for b in range(a + 1, len(seq.cameras)):
            shared[(a, b)] = sum(1 for obs in by_view.values() if {a, b} <= {o.cam for o in obs})
    advice = [s for cc in cams for s in cc.advice]
    for (a, b), n in shared.items():
        if n < min_shared and _needed(a, b, shared, len(seq.cameras), min_shared):
            name_a, name_b = seq.cameras[a].name, seq.cameras[b].name
            advice.append(f"{name_a} and {name_b}: only {n} views where both see the board; add views in their overlap for the extrinsics")
    return Coverage(cams, shared, advice)


def _rim_on_sensor(centre: np.ndarray, R: float, width: int, height: int, inner: float, share: float = 0.2) -> np.ndarray:
    """(sectors,) whether at least ``share`` of each sector's rim ring (``inner`` .. 1 of R) lies
    on the sensor."""
    n = len(SECTORS)
    a = (np.arange(n)[:, None] + np.linspace(-0.5, 0.5, 15)[None, :]) * (2 * math.pi / n)  # (n, 15) angles per sector
    f = np.linspace(inner, 1.0, 5)[None, None, :] * R
    x = centre[0] + np.cos(a)[..., None] * f
    y = centre[1] + np.sin(a)[..., None] * f
    on = (x >= 0) & (x <= width - 1) & (y >= 0) & (y <= height - 1)
    return on.reshape(n, -1).mean(axis=1) >= share


def _needed(a: int, b: int, shared: dict[tuple[int, int], int], n_cams: int, min_shared: int) -> bool:
    """Whether pair (a, b) is an edge the rig needs: without well-shared pairs b is not reached from a."""
    reach, frontier = {a}, [a]
    while frontier:
        c = frontier.pop()
        for (x, y), n in shared.items():
            if n >= min_shared and c in (x, y):
                o = y if c == x else x
                if o not in reach:
                    reach.add(o)
                    frontier.append(o)
    return b not in reach


def _join(words: list[str]) -> str:
    return words[0] if len(words) == 1 else ", ".join(words[:-1]) + " and " + words[-1]
