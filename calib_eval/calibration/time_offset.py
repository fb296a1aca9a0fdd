"""Time offsets between cameras that are not exposed together, from a continuous recording.

Each view's board pose ``T_rig_board`` is the board at the view's stamp, seen by cam0. Another
camera exposed ``dt`` after its stamp saw the board moved along its motion: the pose moved by
``dt`` times the board's velocity (:func:`board_velocities`, central differences of the
neighbouring views' poses: an angular velocity and the velocity of the board's origin).
The motion is taken to second order: the velocity from central differences and its change from
the two one-sided velocities. The solver then estimates each camera's ``dt`` with everything else
(``Free.time``).

A velocity is only defined where the recording is continuous: neighbours within
``max_gap_frames`` frame periods whose motion is smooth (the change of the per-frame motion is
small against the motion itself). Snapshots of a hand-held board (the ROS calibrator's) have no
such neighbours, and then no offset is estimable: the report says so rather than inventing one.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation


@dataclass
class TimeOffsetConfig:
    max_gap_frames: float = 1.5  # neighbours farther apart than this many median frame periods are not one motion
    smooth_ratio: float = 0.5  # the per-frame motion may change by at most this share of itself between the two frames ...
    rot_floor_deg: float = 0.2  # ... plus this much rotation (the pose noise of one view, a few tenths of a degree) ...
    trans_floor_m: float = 0.002  # ... and this much translation (the same, m)
    min_views: int = 10  # co-visible views with a velocity a camera needs for its offset to be estimated
    rounds: int = 2  # estimate, recompute the velocities from the new poses, estimate again


def twist(T_a: np.ndarray, T_b: np.ndarray) -> np.ndarray:
    """(w, u) (6,): the rotation from T_a to T_b as a vector in the rig frame, log(R_b R_a^T), and
    the board origin's displacement t_b - t_a."""
    return np.r_[Rotation.from_matrix(T_b[:3, :3] @ T_a[:3, :3].T).as_rotvec(), T_b[:3, 3] - T_a[:3, 3]]


def board_velocities(
    T_rig_board: dict[int, np.ndarray], stamps_ns: np.ndarray, cfg: TimeOffsetConfig, with_acceleration: bool = False
) -> dict[int, np.ndarray]:
    """Per view with smooth neighbours on both sides: the board's velocity (6,) in the rig frame,
    angular (rad/s) and of its origin (m/s), central differences of its neighbours' poses;
    ``with_acceleration``: (12,), the velocity and its change per second (the difference of the
    two one-sided velocities). ``T_rig_board``: view -> pose; ``stamps_ns``: (n_views,) stamps."""
    views = sorted(T_rig_board)
    if len(views) < 3:
        return {}
    t = stamps_ns[views].astype(np.float64) * 1e-9
    period = float(np.median(np.diff(t)))
    if not period > 0:
        return {}
    out = {}
    for i in range(1, len(views) - 1):
        dt_a, dt_b = t[i] - t[i - 1], t[i + 1] - t[i]
        if not (0 < dt_a <= cfg.max_gap_frames * period and 0 < dt_b <= cfg.max_gap_frames * period):
            continue
        a = twist(T_rig_board[views[i - 1]], T_rig_board[views[i]]) / dt_a
        b = twist(T_rig_board[views[i]], T_rig_board[views[i + 1]]) / dt_b
        step = 0.5 * (dt_a + dt_b)
        rot_ok = (
            np.linalg.norm(a[:3] - b[:3]) <= cfg.smooth_ratio * np.linalg.norm(a[:3] + b[:3]) / 2 + math.radians(cfg.rot_floor_deg) / step
        )
        trans_ok = np.linalg.norm(a[3:] - b[3:]) <= cfg.smooth_ratio * np.linalg.norm(a[3:] + b[3:]) / 2 + cfg.trans_floor_m / step
        if rot_ok and trans_ok:
            v = twist(T_rig_board[views[i - 1]], T_rig_board[views[i + 1]]) / (dt_a + dt_b)
            out[views[i]] = np.r_[v, (b - a) / step] if with_acceleration else v
    return out


@dataclass
class OffsetEstimate:
    """One camera's time offset to cam0: estimated (``value_s``, ``sigma_s``) or why not."""

    camera: str
    value_s: float | None
    sigma_s: float | None
    views: int  # co-visible views with a velocity
    reason: str  # "estimated", or why the offset is not estimable
    shift_px: float | None = None  # median image motion of the board over the offset, px (how much it matters)

    def as_dict(self) -> dict:
        return {
            "value_s": self.value_s,
            "sigma_s": self.sigma_s,
            "views": self.views,
            "reason": self.reason,
            "shift_px": self.shift_px,
        }


def estimable_cameras(
    cams_by_view: dict[int, set[int]], velocities: dict[int, np.ndarray], n_cams: int, cfg: TimeOffsetConfig
) -> dict[int, int]:
    """Per camera 1..: the number of views it shares with cam0 that have a velocity."""
    out = {}
    for c in range(1, n_cams):
        out[c] = sum(1 for v, cams in cams_by_view.items() if v in velocities and c in cams and 0 in cams)
    return out
