"""The detection evaluation's hard conditions: each a row of its own (``calib-eval detection``).

Real recordings have them and our FoV rows mostly do not: a board filling a circular image at its
rim, frames over- or under-exposed, a dull print, motion blur, strong vignetting, glare on the
print. Each condition is a set of :class:`cotrain.render.renderer.RenderConfig` fields changed from
the FoV set's; its frames draw their FoV in 180-240 deg. (A plain dict, so the command line can list them without
loading the renderer.)
"""

from __future__ import annotations

# Rows of their own: frames of one hard condition each (FoV drawn in 180-240 deg), as real
# recordings have them; RenderConfig fields changed from the FoV set's.
CONDITIONS: dict[str, dict] = {
    # Board 6-16 cm away and 55 deg or more off-axis in a circular image: squares of 40-120 px
    # with a strong bend between neighbours, most of the frame filled.
    "large squares at the rim": {"distance_range": (0.06, 0.16), "offaxis_min_deg": 55.0, "radius_range": (0.9, 1.1), "max_tilt_deg": 50.0},
    "over-exposed": {"exposure_range": (1.7, 2.6), "gamma_range": (0.7, 1.0)},  # the whites clip, blacks turn grey
    "under-exposed": {"exposure_range": (0.12, 0.3), "gamma_range": (1.0, 1.4), "noise_range": (0.01, 0.03)},
    "low-contrast print": {"black_range": (0.3, 0.4), "white_range": (0.55, 0.65)},  # grey ink on grey paper
    # 9-15 px along one direction, weighted evenly: the corner's label (the board at mid-exposure)
    # stays at the centre of its blurred image.
    "motion blur": {"p_motion": 1.0, "motion_kernel": (9, 15), "motion_direction": (0.0, 0.0), "p_blur": 0.0},
    "strong vignetting": {"vignette_range": (0.75, 0.9)},  # the rim at 10-25 % of the centre's brightness, 8-bit
    # A glossy print under a lamp: a spot where the light mirrored by the print is as bright as its
    # white or brighter, so the print's contrast fades there and its whites clip.
    "glare": {"p_glare": 1.0},
}
