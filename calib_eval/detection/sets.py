"""The rendered detection sets: which ones thresholds were set on, and how a set's seed is drawn.

A rendered set (``calib-eval detection``: checkerboard, :func:`calib_eval.detection.evaluation.render_benchmark`;
``python -m calib_eval.detection.tags``: AprilGrid, :func:`calib_eval.detection.tags.render_set`)
is named by its seed and its image size. Its frames are drawn from :func:`set_seed` of the two.

Before 2026-12-07 (:data:`REDRAWN`) a set's frames were drawn from its seed alone: a seed drew
the same scenes (poses, lenses, appearance) at every size, so the 1920x1080 set of seed 7 was
the seed-7 tuning set's scenes again, rendered larger. Now the size is mixed into the seed, except
at 1280x720 (:data:`KEPT_SIZE`), whose sets keep their frames, so the figures measured on them
before stay comparable. Sets of other sizes were drawn anew on that day.

:data:`TUNING_SETS` lists every set a threshold or a rule of the detectors was set on, or a change
was kept or dropped on the figures of (from the detector's tuning log, moved from
``docs/detector.md`` into ``CHANGELOG.md`` on 2026-12-07, ``docs/results/*.md`` and
``CHANGELOG.md``). Such a set is never reported as held out: :func:`describe` says which kind a
set is, and the evaluation commands write that line into their reports. A held-out
set is rendered with a seed not listed here, after the thresholds are frozen; once a threshold is
set on it, it goes into this list.

The sets of the independent renderer (``python -m calib_eval.detection.foreign``, seed 5) are
drawn by another code path and are not covered here.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

Kind = Literal["checkerboard", "aprilgrid"]

KEPT_SIZE = (1280, 720)  # sets of this size keep the frames they had before REDRAWN
REDRAWN = "2026-12-07"  # the day sets of every other size were drawn anew (set_seed)
SEED_SCHEME = 2  # 1: the seed alone (before REDRAWN); 2: set_seed. Recorded in a set's cache off KEPT_SIZE.
EVALUATION = {"checkerboard": 2026, "aprilgrid": 2027}  # the evaluation sets' seeds (at KEPT_SIZE)


def set_seed(seed: int, width: int, height: int) -> int:
    """The base seed of the rendered set of ``seed`` at ``width`` x ``height`` (each frame's seed
    is derived from it as before: ``base * 1000 + ...``).

    At 1280x720 it is ``seed``, as it was before :data:`REDRAWN`. At any other size it is
    ``seed + 7919 * width + 104729 * height`` (two primes). Two sizes of one seed never share a
    base (``7919 * dw == -104729 * dh`` needs ``dh`` a multiple of 7919), and a base off 1280x720
    is at least 7919 * 64 + 104729 * 64 (about 7.2 million): it meets no 1280x720 set of a seed
    below that. Two different seeds at two other sizes meet only where the seeds differ by
    ``7919 * dw + 104729 * dh`` of the sizes' differences: never for the seeds and sizes in use
    (``tests/detection/test_sets.py``)."""
    if (width, height) == KEPT_SIZE:
        return seed
    return seed + 7919 * width + 104729 * height


def cache_key(width: int, height: int) -> dict:
    """What a rendered set's cache records of its seeds: nothing at 1280x720, whose frames every
    scheme gives (its caches from before :data:`REDRAWN` stay valid), the scheme at other sizes
    (a cache of the old frames lacks it and is rendered again)."""
    return {} if (width, height) == KEPT_SIZE else {"seed_scheme": SEED_SCHEME}


@dataclass(frozen=True)
class TuningSet:
    kind: Kind
    seed: int
    size: tuple[int, int] | None  # the size its frames were tuned at (None: any size)
    why: str  # what was set on it, in a phrase
    old_seeds: bool = True  # rendered before REDRAWN: its scenes are today the seed's 1280x720 frames

    def marks(self, kind: str, seed: int, width: int, height: int) -> bool:
        """Whether the set of ``seed`` at ``width`` x ``height``, rendered today, shows what was
        tuned on: its frames, or (a set from before :data:`REDRAWN`, when a seed drew the same
        scenes at every size) its scenes, which are now the seed's 1280x720 frames."""
        if kind != self.kind or seed != self.seed:
            return False
        if self.size is None:
            return True
        return (width, height) == (KEPT_SIZE if self.old_seeds else self.size)


TUNING_SETS: tuple[TuningSet, ...] = (
    # ---- checkerboard (calib-eval detection; the grid pass, cotrain/detect/grid_*.py) ----
    # The first tuning set: GridConfig.min_margin was tuned to 18 on it (the tuning log in CHANGELOG.md, "How the
    # thresholds were chosen"; CHANGELOG "Margin threshold 18, tuned on seed 7"); the default of
    # `python -m calib_eval.detection.tuning`; every grid-pass change since is measured on it.
    # Its scenes were also the "seed-7 sets" at 640x480, 1024x1024 and 1920x1080 ("Other image
    # sizes") and held_out_checkerboard.md's "1920x1080, seed 7".
    TuningSet("checkerboard", 7, (1280, 720), "min_margin tuned to 18 on it; the tuning command's default"),
    # The second tuning set: min_margin_votes_alone 30 from its quarter-turned board
    # (strong_vignetting_003, 27.7 nats); min_margin_backed 20 -> 15 on the placements of seeds
    # 2026 / 7 / 11, clean and degraded (its blurred fov240_021). Its scenes were also
    # held_out_checkerboard.md's "1920x1080, seed 11".
    TuningSet("checkerboard", 11, (1280, 720), "min_margin_votes_alone 30 and min_margin_backed 15 set on it"),
    # The evaluation set, which is a tuning set too: min_margin was raised 18 -> 25 after it
    # showed a wrong placement at 22.2 ("that one choice has seen the evaluation set"), and the
    # geometry-backed rule (20 nats where the geometry puts a placement 15 ahead) was "read off
    # the evaluation set's placements" (the tuning log in CHANGELOG.md, "How the thresholds were chosen").
    TuningSet("checkerboard", 2026, (1280, 720), "min_margin raised to 25 on it; min_margin_backed read off it"),
    # Seed 2026's scenes at 640x480: min_margin_votes_alone 30 -> 35 from its fov180_022 (a board
    # placed turned by a quarter at 32.4 nats). Its frames at 1920x1080 and 1024x1024 gated the
    # changes of the same sessions (the tuning log in CHANGELOG.md, step 5; docs/results/size_curve.md).
    TuningSet("checkerboard", 2026, (640, 480), "min_margin_votes_alone 35 from its fov180_022"),
    # Seeds 41 and 53 (with the hard rows) and 67 at 1920x1080: a board placed by the votes alone
    # at 35.2 nats (seed 53, fov180_000) took min_margin_votes_alone to infinity (since the
    # thirtieth session the switch GridConfig.votes_alone, off) and
    # offboard_penalty 10 -> 15, judged over these sets (the tuning log in CHANGELOG.md, "How the thresholds
    # were chosen"); with 2026, 7, 11, 31 at 1024x768 they are "the seven rendered sets" later
    # grid-pass changes are kept on (e.g. the lattice split at a margin line, step 5).
    TuningSet("checkerboard", 41, (1280, 720), "offboard_penalty 15 and votes alone off judged on it; gates changes"),
    TuningSet("checkerboard", 53, (1280, 720), "min_margin_votes_alone infinite and offboard_penalty 15 from its fov180_000"),
    TuningSet("checkerboard", 67, (1920, 1080), "offboard_penalty 15 and votes alone off judged on it"),
    # Seed 31: at 1024x768 one of the seven sets the change above was judged over, and the
    # bench's second set (docs/benchmarks.md); at 1920x1080 ("held-out" in
    # held_out_checkerboard.md) its large-squares frame 9 gave identity.board_goes_on
    # (GridConfig.goes_on_*; CHANGELOG, twenty-fourth session); at 640x480 (the eleven sets'
    # 640x480 one) a motion-blurred board set that rule's floor of 15 px steps (same entry).
    TuningSet("checkerboard", 31, (1024, 768), "offboard_penalty 15 and votes alone off judged on it"),
    TuningSet("checkerboard", 31, (1920, 1080), "GridConfig.goes_on_* (identity.board_goes_on) from its large-squares frame 9"),
    TuningSet("checkerboard", 31, (640, 480), "the goes_on_* floor of 15 px from its motion-blurred board"),
    # Seed 71 at 640x480 (146 frames): rendered after the votes-alone change, it then joined the
    # seven sets above as "the eight checkerboard sets" (1,566 + 146 = 1,712 frames, CHANGELOG)
    # every grid-pass change since is kept or dropped on.
    TuningSet("checkerboard", 71, (640, 480), "one of the eight sets every grid-pass change is gated on"),
    # Seed 97, the first set rendered after the thresholds were set (the tuning log in CHANGELOG.md): two rules
    # were then made from its large-squares frames, margin_max_brighter (a light occluder read as
    # margin) and grid_pass.extent_weight (no extent evidence near the rim at half resolution).
    TuningSet("checkerboard", 97, (1280, 720), "margin_max_brighter and extent_weight made from its frames"),
    # Seed 99 (1280x1024 in the tuning log in CHANGELOG.md, 1024x1024 in held_out_checkerboard.md): changes were
    # tried and dropped on the held-out sets' figures ("Tried and not kept"), this one among them;
    # so were seeds 7, 11 and 31 at 1920x1080, 31 at 640x480 and 97 (listed above).
    TuningSet("checkerboard", 99, (1024, 1024), "changes tried and dropped on its figures"),
    # ---- AprilGrid (python -m calib_eval.detection.tags; the tag pass, cotrain/detect/tag_*.py) ----
    # The AprilGrid evaluation set, a tuning set too: the tag pass's thresholds were set on it
    # (e.g. keep_unfitted_px and max_ray_angle_small "on the evaluation set and two sets of other
    # seeds", retry_seed_angle 16 deg from its fov180_013, the print check's margins, the image
    # circle's draws; the tuning log in CHANGELOG.md, "AprilGrid", steps 1-13; docs/results/tags.md).
    TuningSet("aprilgrid", 2027, (1280, 720), "the tag pass's thresholds set on it (retry_seed_angle, keep_unfitted_px, ...)"),
    # The "two more sets of other seeds" (40 and 30 frames per FoV): keep_unfitted_px (6 px, "up to
    # 10 px brought two wrong ones") and max_ray_angle_small (30 deg) chosen on them with 2027.
    TuningSet("aprilgrid", 2031, (1280, 720), "keep_unfitted_px and max_ray_angle_small chosen on it"),
    TuningSet("aprilgrid", 2035, (1280, 720), "keep_unfitted_px and max_ray_angle_small chosen on it"),
    # The "validation set": TagConfig.min_mean_corr 0.4 -> 0.3 from its fov200_024
    # (tests/detection/test_tags_eval.py renders it again); every tag-pass change is gated on it.
    # At 1920x1080 (12 per FoV, blurred): the half-resolution pass's gate (under 70 corners) weighed on it.
    TuningSet("aprilgrid", 2041, (1280, 720), "min_mean_corr 0.3 from its fov200_024; gates every change"),
    TuningSet("aprilgrid", 2041, (1920, 1080), "the half-resolution pass's gate weighed on its blurred frames"),
    # 640x480 (seeds 2042, 2045), 512x512 (2043) and 848x800 (2044): TagConfig.min_side_px 720,
    # max_enlarge 1.5 and bilinear over bicubic chosen on them; print_moved from seed 2045's
    # fov220_004 (docs/results/tags_640x480.md). Seed 2043 at 1920x1080 / 1920x1200, called
    # held out, gated every change of the sixteenth and later sessions (CHANGELOG).
    TuningSet("aprilgrid", 2042, (640, 480), "min_side_px and max_enlarge chosen on it"),
    TuningSet("aprilgrid", 2045, (640, 480), "min_side_px and max_enlarge chosen on it; print_moved from its fov220_004"),
    TuningSet("aprilgrid", 2043, (512, 512), "min_side_px and max_enlarge chosen on it"),
    TuningSet("aprilgrid", 2043, (1920, 1080), "gates every tag-pass change since the sixteenth session"),
    TuningSet("aprilgrid", 2044, (848, 800), "min_side_px 720 (no enlargement at 800 px) chosen on it"),
    # Redrawn on REDRAWN and then used the same day to judge a change: the checkerboard's
    # half-resolution gate (half_min_side) was removed where these sets showed no row regressing.
    TuningSet("checkerboard", 2026, (640, 480), "the removal of half_min_side judged on it (2026-12-07)", old_seeds=False),
    TuningSet("checkerboard", 31, (640, 480), "the removal of half_min_side judged on it (2026-12-07)", old_seeds=False),
    # Rendered on 2026-12-07 to design a check of the parts that cut_at_margins places (the wrong
    # corners of docs/results/rule_ablations.md) without looking at the held-out sets' frames.
    TuningSet("checkerboard", 5150, (1920, 1080), "the cut parts' check designed on it (2026-12-07)", old_seeds=False),
    TuningSet("checkerboard", 5151, (640, 480), "the cut parts' check designed on it (2026-12-07)", old_seeds=False),
    # Rendered on 2026-12-07 to look for wrong placements of the kinds the held-out sets show (glare,
    # strong vignetting and motion blur at 1920x1080 and 1024x1024) without looking at those frames.
    TuningSet("checkerboard", 5152, (1920, 1080), "identity failures under glare, vignetting, blur sought (2026-12-07)", old_seeds=False),
    TuningSet("checkerboard", 5153, (1024, 1024), "identity failures under motion blur looked for (2026-12-07)", old_seeds=False),
)


# The independent renderer's sets (python -m calib_eval.detection.foreign, seed 5) that thresholds
# were set or judged on, by their regression names (calib_eval.detection.regression), with the
# evidence; found by reading the tuning log for each threshold's origin (2026-12-07).
FOREIGN_TUNING = {
    "foreign_checkerboard": "one of 'the eleven sets' the grid pass's later rules were judged over (the tuning log)",
    "foreign_checkerboard_photo": "one of 'the eleven sets'; GREY_PRINT_GAIN 3 measured on it",
    "foreign_checkerboard_isp": "one of 'the eleven sets' (the tuning log)",
    "foreign_aprilgrid": "CompletionConfig.small_gap_px 4 -> 7 from its fov220_004",
    "foreign_aprilgrid_photo": "CompletionConfig.dim_gaps from its fov220_014; TagConfig.retry_gain",
    "foreign_aprilgrid_isp": "CompletionConfig.check_min_corr_large 0.1 from its two wrong corners",
    "foreign_aprilgrid_defocus": "print_moved judged on it (6 -> 3 wrong)",
}


def tuning_sets(kind: str, seed: int, width: int, height: int) -> list[TuningSet]:
    """The entries of :data:`TUNING_SETS` that mark the set of ``seed`` at ``width`` x ``height``."""
    return [t for t in TUNING_SETS if t.marks(kind, seed, width, height)]


def is_tuning(kind: str, seed: int, width: int, height: int) -> bool:
    """Whether thresholds were set on the set of ``seed`` at ``width`` x ``height`` (its frames,
    or its scenes at another size before :data:`REDRAWN`): then it is never reported as held out."""
    return bool(tuning_sets(kind, seed, width, height))


def describe(kind: str, seed: int, width: int, height: int) -> str:
    """One line for a report: which kind of set this is.

    ``"checkerboard tuning set (seed 7, 1280x720): thresholds were set on it (...); not held out"``,
    ``"checkerboard held-out set (seed 31, 640x480): no threshold was set on it (...)"``."""
    name = f"seed {seed}, {width}x{height}"
    if seed == EVALUATION.get(kind) and (width, height) == KEPT_SIZE:
        name += "; the evaluation set"
    found = tuning_sets(kind, seed, width, height)
    if not found:
        return (
            f"{kind} held-out set ({name}): no threshold was set on it "
            "(calib_eval/detection/sets.py lists the tuning sets; one tuned on joins them)"
        )
    whys = []
    for t in found:
        at = "" if t.size in (None, (width, height)) else f"its scenes at {t.size[0]}x{t.size[1]} before {REDRAWN}: "
        whys.append(at + t.why)
    return f"{kind} tuning set ({name}): thresholds were set on it ({'; '.join(whys)}); not held out"
