"""Scale and place monocular reconstructions in the metric GPS frame (the paper's eq. 5-6).

Each window alone is placed by one Umeyama similarity to the GPS fixes of its frames
(``align_window``), i.e. shifted by the GPS bias averaged over its frames (~0.5 m on the
synthetic journeys, whose bias stays correlated over ~40-60 frames); frames inside a GPS dropout
(``gps_track.in_dropout``) are left out of the fit and of the residual (``fit_rows``).
``align_windows`` aligns windows that pose the same frames (chained by
``ego_motion.plan_windows``) jointly: they must agree on those frames, so a whole chain averages
the bias over its length. A short stretch of
straight road leaves the roll about the road undetermined by positions;
``geometry.similarity.align_trajectory`` fixes it from gravity, and the joint fit keeps it. A
window whose own alignment lies further from the GPS than the broken-reconstruction limit is
mended where a run of bad fixes explains it (``mend``), else its signs are refused.

``track_poses`` gives a sign its frames' poses: ``full`` from its chain; ``short`` (the paper's
best against ORB-SLAM's drift) from one window aligned again over only the frames around the sign
(leaving out a dropout's frames, as the windows do).
"""

from __future__ import annotations

import logging
from dataclasses import replace
from typing import Callable

import numpy as np

from app.pipeline.steps.align.joint import JointSigmas, align_group
from app.pipeline.steps.align.mend import Mend, mend_window
from app.pipeline.steps.align.track_poses import TrackPoses, track_poses
from app.pipeline.steps.align.window import (AlignedWindow, align_window, centre_rms_m,
                                             fit_rows, shared_rows)
from app.pipeline.steps.ego_motion import WindowPoses
from app.pipeline.types import StageReport

__all__ = ["AlignedWindow", "JointSigmas", "Mend", "TrackPoses", "align_window", "align_windows",
           "fit_rows", "report", "track_poses"]

log = logging.getLogger(__name__)


def align_windows(poses: list[WindowPoses], xyz_gps: np.ndarray, *, joint: bool = True,
                  sigmas: JointSigmas = JointSigmas(), min_shared_frames: int = 2,
                  max_independent_rms_m: float | None = None,
                  on_dropped: Callable[[WindowPoses, str], None] | None = None,
                  xyz_check: np.ndarray | None = None,
                  trusted: np.ndarray | None = None, mend_broken: bool = False,
                  on_broken: Callable[[AlignedWindow, Mend], None] | None = None,
                  min_fixes: int = 10) -> list[AlignedWindow]:
    """Alignment of every window to ``xyz_gps`` (N, 3), the whole journey's metric GPS.

    Each window is first aligned on its own (``align_window``, which handles the straight-road
    roll); a window that cannot be (the car stood still) is logged, passed to
    ``on_dropped(window, reason)`` and left out. With ``joint``,
    windows linked by at least ``min_shared_frames`` common registered frames are then aligned
    together (``align_group``); a window linked to none keeps its own alignment. A window whose
    own alignment leaves more than ``max_independent_rms_m`` of GPS residual is a broken
    reconstruction: it is linked to none, since the shared frames' agreement would bend its
    neighbours onto it (corpus c0016: a window following its fixes to 0.37 m was dragged to
    13.7 m rms by two bent neighbours, and lost its signs). That residual is measured against
    ``xyz_check`` (N, 3) when given: the fixes as read, where ``xyz_gps`` is smoothed (a bent
    window that lay 1.32 m off the fixes, just past c0016's limit, lay under it against the
    smoothed positions, was linked, and dragged its chain 11.6 m off); the windows returned then
    report their residual (``info["rms_m"]``) against ``xyz_check`` too (``_with_residuals_to``).
    ``trusted`` (N,) bool: the frames whose GPS positions fit and judge the windows (``fit_rows``:
    a dropout's interpolated positions neither pull a window nor make it look broken).
    With ``mend_broken``, a broken window is replaced by what ``mend.mend_window`` makes of it
    (aligned on at least ``min_fixes`` fixes), and both are passed to ``on_broken``; a mended
    window is linked to none either.
    """
    aligned = []
    for p in poses:
        try:
            aligned.append(align_window(p, xyz_gps, trusted))
        except ValueError as exc:
            log.warning("window frames %d-%d not aligned to GPS: %s", *p.window, exc)
            if on_dropped is not None:
                on_dropped(p, str(exc))
    if max_independent_rms_m is not None:
        checked = (aligned if xyz_check is None else
                   _with_residuals_to(aligned, xyz_check, trusted))
        aligned = _mended(aligned, checked, xyz_gps, max_independent_rms_m, xyz_check, trusted,
                          min_fixes, on_broken, mend=mend_broken)
    if joint:
        linkable = [not w.info.get("broken") and "mend" not in w.info for w in aligned]
        for g, group in enumerate(_linked_groups([w.poses for w in aligned], min_shared_frames,
                                                 linkable)):
            joint_windows = ([aligned[group[0]]] if len(group) == 1 else
                             align_group([aligned[k] for k in group], xyz_gps, sigmas,
                                         trusted))
            for k, window in zip(group, joint_windows):
                aligned[k] = replace(window, info={**window.info, "group": g})
    return aligned if xyz_check is None else _with_residuals_to(aligned, xyz_check, trusted)


def _with_residuals_to(aligned: list[AlignedWindow], xyz: np.ndarray,
                       trusted: np.ndarray | None = None) -> list[AlignedWindow]:
    """The windows with ``info["rms_m"]`` measured against the positions ``xyz`` (N, 3) instead
    of those they were aligned to (kept as ``rms_fit_m``). Aligned to smoothed GPS positions, a
    window's residual no longer holds the GPS's white noise, while the broken-reconstruction
    check and the sign uncertainty were chosen on residuals to the fixes as read."""
    out = []
    for w in aligned:
        if "mend" in w.info:  # judged against the fixes as read when it was mended
            out.append(w)
            continue
        use = fit_rows(w.poses.frame_idx, trusted)
        out.append(replace(w, info={**w.info, "rms_fit_m": w.info["rms_m"], "rms_m": centre_rms_m(
            w.T_world_cam[use], xyz[w.poses.frame_idx[use]])}))
    return out


def _mended(aligned: list[AlignedWindow], checked: list[AlignedWindow], xyz_gps: np.ndarray,
            limit_m: float, xyz_check: np.ndarray | None, trusted: np.ndarray | None,
            min_fixes: int, on_broken: Callable[[AlignedWindow, Mend], None] | None, *,
            mend: bool) -> list[AlignedWindow]:
    """``aligned`` with each broken window (``checked``: the same windows, their residuals to
    ``xyz_check``, over ``limit_m``) marked ``info["broken"]``, and with ``mend`` replaced by what
    ``mend.mend_window`` makes of it, its ``info["mend"]`` saying how. ``on_broken`` hears of
    every broken window, mended or not."""
    broken = [c.info["rms_m"] > limit_m for c in checked]
    good = [w for w, b in zip(aligned, broken) if not b]
    out = []
    for w, c, b in zip(aligned, checked, broken):
        if not b:
            out.append(w)
            continue
        fix = (mend_window(c, xyz_gps, limit_m, xyz_check=xyz_check, trusted=trusted,
                           min_frames=min_fixes, neighbours=good) if mend else
               Mend(replace(c, info={**c.info, "broken": True}),
                    "not mended (alignment_mend_broken is off)"))
        log.info("window frames %d-%d broken (GPS rms %.2f m, over %.2f m): %s", *c.poses.window,
                 c.info["rms_m"], limit_m, fix.how)
        if on_broken is not None:
            on_broken(c, fix)
        out.append(replace(fix.window, info={**fix.window.info, "mend": fix.how}) if mend
                   else replace(w, info={**w.info, "broken": True}))
    return out


def report(n_windows: int, aligned: list[AlignedWindow], notes: list[str]) -> StageReport:
    """The align stage's report: the windows aligned (their GPS residual), then ``notes``, one
    line each: frames left out as GPS dropouts, windows dropped (``align_windows(on_dropped=
    ...)``), windows broken and how they ended (``on_broken``)."""
    chains = len({w.info.get("group") for w in aligned if "group" in w.info})
    summary = f"{len(aligned)} of {n_windows} windows aligned to GPS"
    if chains:
        summary += f" in {chains} joint group(s)"
    details = tuple(f"frames {w.poses.window[0]}-{w.poses.window[1] - 1}: GPS rms "
                    f"{w.info['rms_m']:.2f} m" for w in aligned)
    return StageReport("align", summary, details + tuple(notes))


def _linked_groups(poses: list[WindowPoses], min_shared: int,
                   linkable: list[bool] | None = None) -> list[list[int]]:
    """Indices of ``poses`` grouped by chains of windows sharing >= ``min_shared`` frames; a
    window not ``linkable`` is a group of its own."""
    group = list(range(len(poses)))

    def root(k: int) -> int:
        while group[k] != k:
            k = group[k]
        return k

    linkable = linkable or [True] * len(poses)
    for i in range(len(poses)):
        for j in range(i + 1, len(poses)):
            if (linkable[i] and linkable[j]
                    and len(shared_rows(poses[i], poses[j])[0]) >= min_shared):
                group[root(j)] = root(i)
    out: dict[int, list[int]] = {}
    for k in range(len(poses)):
        out.setdefault(root(k), []).append(k)
    return list(out.values())
