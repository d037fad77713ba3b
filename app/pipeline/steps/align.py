"""Scale and place monocular reconstructions in the metric GPS frame (the paper's eq. 5-6).

Each window alone is placed by one Umeyama similarity to the GPS fixes of its frames
(``align_window``), i.e. shifted by the GPS bias averaged over its frames (~0.5 m on the
synthetic journeys, whose bias stays correlated over ~40-60 frames); frames inside a GPS dropout
(``gps_track.in_dropout``) are left out of the fit and of the residual (``fit_rows``).
``align_windows`` aligns windows that pose the same frames (chained by
``ego_motion.plan_windows``) jointly: they must agree on those frames, so a whole chain averages
the bias over its length. A short stretch of
straight road leaves the roll about the road undetermined by positions;
``geometry.similarity.align_trajectory`` fixes it from gravity, and the joint fit keeps it.

``track_poses`` gives a sign its frames' poses: ``full`` from its chain; ``short`` (the paper's
best against ORB-SLAM's drift) from one window aligned again over only the frames around the sign
(leaving out a dropout's frames, as the windows do).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, replace
from typing import Callable

import numpy as np
from scipy import sparse
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from app.pipeline.geometry.similarity import Sim3, align_trajectory
from app.pipeline.steps.ego_motion import WindowPoses
from app.pipeline.steps.sign_tracks import SignTrack
from app.pipeline.types import StageReport

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class AlignedWindow:
    poses: WindowPoses
    sim: Sim3
    info: dict
    T_world_cam: np.ndarray  # (K, 4, 4) aligned poses of poses.frame_idx


def align_window(poses: WindowPoses, xyz_gps: np.ndarray,
                 trusted: np.ndarray | None = None) -> AlignedWindow:
    """Full alignment of one window; ``xyz_gps`` (N, 3) is the whole journey's metric GPS,
    ``trusted`` (N,) bool the frames whose GPS position may be used (``fit_rows``)."""
    use = fit_rows(poses.frame_idx, trusted)
    centres = poses.T_model_cam[use, :3, 3]
    sim, info = align_trajectory(centres, xyz_gps[poses.frame_idx[use]],
                                 poses.T_model_cam[use, :3, :3])
    return AlignedWindow(poses, sim, info, sim.apply_poses(poses.T_model_cam))


# A window needs this many frames, and this share of its own, with trusted GPS positions to be
# aligned by those alone; else by all its frames, as before the dropout mask.
MIN_TRUSTED_FRAMES = 6
MIN_TRUSTED_SHARE = 1 / 3


def fit_rows(frame_idx: np.ndarray, trusted: np.ndarray | None) -> np.ndarray:
    """(K,) bool over a window's frames ``frame_idx``: those whose GPS position aligns and judges
    it. ``trusted`` (N,) bool over the journey's frames (None: all; ``gps_track.in_dropout``
    marks the rest)."""
    if trusted is None:
        return np.ones(len(frame_idx), bool)
    use = np.asarray(trusted, bool)[frame_idx]
    if use.sum() < max(MIN_TRUSTED_FRAMES, MIN_TRUSTED_SHARE * len(frame_idx)):
        return np.ones(len(frame_idx), bool)
    return use


@dataclass(frozen=True, kw_only=True)
class JointSigmas:
    """1-sigma errors of the joint alignment's residuals. ``gps_m``: a GPS fix (per axis);
    ``centre_m`` / ``rotation_deg``: how closely two windows' world poses of one frame agree (both
    are reconstructions of the same images); ``roll_deg``: the prior that keeps a straight-road
    window's roll about the road at its independent (gravity or fallback) value."""

    gps_m: float = 0.5
    centre_m: float = 0.03
    rotation_deg: float = 0.2
    roll_deg: float = 1.0


# The robust loss (soft L1) is quadratic up to this many sigmas: a window whose reconstruction
# bends cannot drag its neighbours far.
ROBUST_SCALE_SIGMAS = 2.0


def align_windows(poses: list[WindowPoses], xyz_gps: np.ndarray, *, joint: bool = True,
                  sigmas: JointSigmas = JointSigmas(), min_shared_frames: int = 2,
                  max_independent_rms_m: float | None = None,
                  on_dropped: Callable[[WindowPoses, str], None] | None = None,
                  xyz_check: np.ndarray | None = None,
                  trusted: np.ndarray | None = None) -> list[AlignedWindow]:
    """Alignment of every window to ``xyz_gps`` (N, 3), the whole journey's metric GPS.

    Each window is first aligned on its own (``align_window``, which handles the straight-road
    roll); a window that cannot be (the car stood still) is logged, passed to
    ``on_dropped(window, reason)`` and left out. With ``joint``,
    windows linked by at least ``min_shared_frames`` common registered frames are then aligned
    together (``_align_group``); a window linked to none keeps its own alignment. A window whose
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
    """
    aligned = []
    for p in poses:
        try:
            aligned.append(align_window(p, xyz_gps, trusted))
        except ValueError as exc:
            log.warning("window frames %d-%d not aligned to GPS: %s", *p.window, exc)
            if on_dropped is not None:
                on_dropped(p, str(exc))
    if joint:
        checked = aligned if xyz_check is None else _with_residuals_to(aligned, xyz_check,
                                                                        trusted)
        linkable = [max_independent_rms_m is None or w.info["rms_m"] <= max_independent_rms_m
                    for w in checked]
        for g, group in enumerate(_linked_groups([w.poses for w in aligned], min_shared_frames,
                                                 linkable)):
            joint_windows = ([aligned[group[0]]] if len(group) == 1 else
                             _align_group([aligned[k] for k in group], xyz_gps, sigmas,
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
        use = fit_rows(w.poses.frame_idx, trusted)
        out.append(replace(w, info={**w.info, "rms_fit_m": w.info["rms_m"], "rms_m": _centre_rms_m(
            w.T_world_cam[use], xyz[w.poses.frame_idx[use]])}))
    return out


def _centre_rms_m(T_world_cam: np.ndarray, xyz: np.ndarray) -> float:
    """Rms distance (m) of the camera centres of ``T_world_cam`` (K, 4, 4) from ``xyz`` (K, 3)."""
    return float(np.sqrt(np.mean(np.sum((T_world_cam[:, :3, 3] - xyz) ** 2, axis=1))))


def report(n_windows: int, aligned: list[AlignedWindow], notes: list[str]) -> StageReport:
    """The align stage's report: the windows aligned (their GPS residual), then ``notes``, one
    line each: frames left out as GPS dropouts, windows dropped (``align_windows(on_dropped=
    ...)``)."""
    chains = len({w.info.get("group") for w in aligned if "group" in w.info})
    summary = f"{len(aligned)} of {n_windows} windows aligned to GPS"
    if chains:
        summary += f" in {chains} joint group(s)"
    details = tuple(f"frames {w.poses.window[0]}-{w.poses.window[1] - 1}: GPS rms "
                    f"{w.info['rms_m']:.2f} m" for w in aligned)
    return StageReport("align", summary, details + tuple(notes))


def _shared_rows(a: WindowPoses, b: WindowPoses) -> tuple[np.ndarray, np.ndarray]:
    """Rows of ``a`` and of ``b`` that pose the same journey frames, (S,) each, in frame order."""
    _, rows_a, rows_b = np.intersect1d(a.frame_idx, b.frame_idx, assume_unique=True,
                                       return_indices=True)
    return rows_a, rows_b


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
                    and len(_shared_rows(poses[i], poses[j])[0]) >= min_shared):
                group[root(j)] = root(i)
    out: dict[int, list[int]] = {}
    for k in range(len(poses)):
        out.setdefault(root(k), []).append(k)
    return list(out.values())


class _JointProblem:
    """The joint alignment of linked windows as a least-squares problem.

    Unknowns: per window a similarity correction (rotation vector 3, translation 3, log scale 1)
    applied in the world frame after the window's independent alignment, rotating about the
    window's world centroid (a rotation about the distant ENU origin would be tangled with the
    translation). Residuals, each divided by its sigma: (a) camera centres vs GPS, a frame's fix
    weighted 1/sqrt(number of windows posing it) so a shared frame counts once; (b) per frame
    posed by two windows, their world camera centres and rotations agree; (c) a window whose
    roll about its road line is unobserved keeps its independent roll.
    """

    def __init__(self, windows: list[AlignedWindow], xyz_gps: np.ndarray, sigmas: JointSigmas,
                 trusted: np.ndarray | None = None):
        self.windows = windows
        self.sigmas = sigmas
        self.centres_model = [w.poses.T_model_cam[:, :3, 3] for w in windows]  # (K,3) each
        self.R_model_cam = [w.poses.T_model_cam[:, :3, :3] for w in windows]  # (K,3,3) each
        self.xyz_gps = [xyz_gps[w.poses.frame_idx] for w in windows]  # (K,3) each
        counts = np.bincount(np.concatenate([w.poses.frame_idx for w in windows]))
        # A frame whose GPS position is not trusted (``fit_rows``) weighs nothing.
        self.gps_weight = [fit_rows(w.poses.frame_idx, trusted)
                           / (sigmas.gps_m * np.sqrt(counts[w.poses.frame_idx]))
                           for w in windows]  # (K,) each
        self.pivot_enu = [w.T_world_cam[:, :3, 3].mean(0) for w in windows]
        self.pairs = [(i, j, *_shared_rows(windows[i].poses, windows[j].poses))
                      for i in range(len(windows)) for j in range(i + 1, len(windows))]
        self.pairs = [p for p in self.pairs if len(p[2])]
        self.roll_axes = [(k, _line_direction(w.T_world_cam[:, :3, 3]))
                          for k, w in enumerate(windows) if w.info.get("degenerate")]

    def sims(self, x: np.ndarray) -> list[Sim3]:
        """Model -> world similarity of every window for the corrections x (7 * n_windows,)."""
        out = []
        for w, pivot, dx in zip(self.windows, self.pivot_enu, x.reshape(-1, 7)):
            R_delta = Rotation.from_rotvec(dx[:3]).as_matrix()
            k = np.exp(dx[6])
            out.append(Sim3(k * w.sim.scale, R_delta @ w.sim.R,
                            pivot + k * R_delta @ (w.sim.t - pivot) + dx[3:6]))
        return out

    def residuals(self, x: np.ndarray) -> np.ndarray:
        sims = self.sims(x)
        xyz_world = [sim.apply(c) for sim, c in zip(sims, self.centres_model)]
        R_world_cam = [sim.R @ R for sim, R in zip(sims, self.R_model_cam)]
        parts = [((xyz - gps) * wt[:, None]).ravel()
                 for xyz, gps, wt in zip(xyz_world, self.xyz_gps, self.gps_weight)]
        for i, j, rows_i, rows_j in self.pairs:
            parts.append((xyz_world[i][rows_i] - xyz_world[j][rows_j]).ravel()
                         / self.sigmas.centre_m)
            R_i_j = R_world_cam[i][rows_i] @ np.transpose(R_world_cam[j][rows_j], (0, 2, 1))
            parts.append(Rotation.from_matrix(R_i_j).as_rotvec().ravel()
                         / np.radians(self.sigmas.rotation_deg))
        dx = x.reshape(-1, 7)
        parts.append(np.array([dx[k, :3] @ u for k, u in self.roll_axes])
                     / np.radians(self.sigmas.roll_deg))
        return np.concatenate(parts)

    def jac_sparsity(self) -> sparse.lil_matrix:
        """Which unknowns each residual depends on, in ``residuals``' order: a window's GPS rows
        on its own 7, a shared frame's rows on its two windows' 14. Finite differences then cost
        a few evaluations per Jacobian instead of 7 per window (a 1000-frame journey chains ~50
        windows)."""
        blocks = [(3 * len(c), (k,)) for k, c in enumerate(self.centres_model)]
        blocks += [(6 * len(rows_i), (i, j)) for i, j, rows_i, _ in self.pairs]
        blocks += [(1, (k,)) for k, _ in self.roll_axes]
        out = sparse.lil_matrix((sum(n for n, _ in blocks), 7 * len(self.windows)), dtype=int)
        row = 0
        for n, ks in blocks:
            for k in ks:
                out[row:row + n, 7 * k:7 * k + 7] = 1
            row += n
        return out

    def pair_disagreement_m(self, sims: list[Sim3]) -> float:
        """Rms distance (m) between two windows' world centres of the frames they share."""
        d = [sims[i].apply(self.centres_model[i][ri]) - sims[j].apply(self.centres_model[j][rj])
             for i, j, ri, rj in self.pairs]
        return float(np.sqrt(np.mean(np.sum(np.concatenate(d) ** 2, axis=1))))


def _line_direction(xyz: np.ndarray) -> np.ndarray:
    """Unit direction (3,) of the best-fit line of the points (K,3)."""
    return np.linalg.svd(xyz - xyz.mean(0), full_matrices=False)[2][0]


def _align_group(windows: list[AlignedWindow], xyz_gps: np.ndarray,
                 sigmas: JointSigmas, trusted: np.ndarray | None = None) -> list[AlignedWindow]:
    """Joint alignment of linked windows (see ``_JointProblem``), started from their independent
    alignments. Each window's ``info`` keeps its independent values, with ``rms_m`` and ``scale``
    of the joint alignment and ``rms_independent_m``, ``joint_windows`` added."""
    problem = _JointProblem(windows, xyz_gps, sigmas, trusted)
    # lsmr, not the dense SVD solver: same solution (to 1e-6 m on the tests), but the SVD's
    # threaded LAPACK spun 10x the CPU time while COLMAP busied the other core.
    fit = least_squares(problem.residuals, np.zeros(7 * len(windows)), loss="soft_l1",
                        f_scale=ROBUST_SCALE_SIGMAS, x_scale="jac", tr_solver="lsmr",
                        jac_sparsity=problem.jac_sparsity())
    sims = problem.sims(fit.x)
    out = []
    for w, sim, gps in zip(windows, sims, problem.xyz_gps):
        T_world_cam = sim.apply_poses(w.poses.T_model_cam)
        use = fit_rows(w.poses.frame_idx, trusted)
        info = {**w.info, "rms_m": _centre_rms_m(T_world_cam[use], gps[use]), "scale": sim.scale,
                "rms_independent_m": w.info["rms_m"], "joint_windows": len(windows)}
        out.append(AlignedWindow(w.poses, sim, info, T_world_cam))
    log.info("joint alignment of windows %s: GPS rms %.3f -> %.3f m, shared frames disagree "
             "%.3f -> %.3f m rms (%d evaluations)", [w.poses.window for w in windows],
             _pooled_rms([w.info["rms_m"] for w in windows], windows),
             _pooled_rms([w.info["rms_m"] for w in out], windows),
             problem.pair_disagreement_m([w.sim for w in windows]),
             problem.pair_disagreement_m(sims), fit.nfev)
    return out


def _pooled_rms(rms_m: list[float], windows: list[AlignedWindow]) -> float:
    n = np.array([len(w.poses.frame_idx) for w in windows])
    return float(np.sqrt(np.sum(n * np.square(rms_m)) / n.sum()))


@dataclass(frozen=True)
class TrackPoses:
    """Aligned poses of the track's frames that were reconstructed: ``keep`` (M,) bool mask over the
    track's detections, ``T_world_cam`` (keep.sum(), 4, 4)."""

    keep: np.ndarray
    T_world_cam: np.ndarray
    alignment_rms_m: float  # GPS residual rms of the alignment that placed them
    alignment_n: int  # GPS fixes in that alignment
    # GPS residual rms of the window's (or chain's) own alignment: whether the reconstruction
    # broke is judged on it, since a fit over the few frames by a sign can follow a broken one.
    window_rms_m: float


def track_poses(track: SignTrack, windows: list[AlignedWindow], xyz_gps: np.ndarray, *,
                mode: str, margin: int, min_frames: int, local_weight: float = 1.0,
                trusted: np.ndarray | None = None) -> TrackPoses | None:
    """Poses for a sign's frames. ``full``: from the window that reconstructed most of them,
    completed by the windows aligned jointly with it; ``short``: that window alone, aligned again
    to the GPS around the sign (the paper's short trajectories); ``local``: the ``full`` poses,
    their chain aligned again to the GPS around the sign (so a sign spanning two windows keeps
    all its frames), that correction taken ``local_weight`` of the way (``Sim3.partial``): over
    a few seconds the GPS fixes scale about as well as the reconstruction holds it, so the best
    estimate lies between the two. ``trusted`` (N,) bool over the journey's frames:
    those whose GPS position may align the frames around the sign (None: all)."""
    def coverage(w: AlignedWindow) -> int:
        return int(np.isin(track.frame_idx, w.poses.frame_idx).sum())

    best = max(windows, key=coverage, default=None)
    if best is None or coverage(best) < 2:
        return None
    if mode == "full":
        return _chained_poses(track, best, windows)
    # The poses aligned again (``T_from_cam``: the chain's world poses, or the window's model
    # poses), and those already placed, which stand when they cannot be aligned again.
    if mode == "local":
        frame_idx, T_world_cam = _chain_trajectory(best, windows)
        T_from_cam, start_rotation = T_world_cam, np.eye(3)  # in the world: keep the chain's roll
    else:
        frame_idx, T_world_cam = best.poses.frame_idx, best.T_world_cam
        T_from_cam, start_rotation = best.poses.T_model_cam, best.sim.R
    keep = np.isin(track.frame_idx, frame_idx)
    rows = np.searchsorted(frame_idx, track.frame_idx[keep])
    placed = TrackPoses(keep, T_world_cam[rows], *_fit(best.info), best.info["rms_m"])
    a, b = track.span
    near = (frame_idx >= a - margin) & (frame_idx < b + margin)
    # A dropout's interpolated positions cut a bend's corner: over the few seconds by a sign
    # they would pull the poses by metres. Too few frames left: the window's own alignment,
    # which left them out, stands.
    if trusted is not None:
        near &= np.asarray(trusted, bool)[frame_idx]
    if near.sum() < min_frames:
        return placed
    try:
        sim, info = align_trajectory(T_from_cam[near, :3, 3], xyz_gps[frame_idx[near]],
                                     T_from_cam[near, :3, :3], R_fallback=start_rotation)
    except ValueError:  # the car stood still by this sign: the window's alignment must do
        return placed
    if mode == "local" and local_weight != 1.0:
        sim = sim.partial(local_weight, T_from_cam[near, :3, 3].mean(0))
        info = {**info, "rms_m": _centre_rms_m(sim.apply_poses(T_from_cam[near]),
                                               xyz_gps[frame_idx[near]])}
    return TrackPoses(keep, sim.apply_poses(T_from_cam[rows]), *_fit(info), best.info["rms_m"])


def _fit(info: dict) -> tuple[float, int]:
    """(rms_m, n) of an alignment's info."""
    return float(info["rms_m"]), int(info.get("n", 0))


def _chain_trajectory(best: AlignedWindow, windows: list[AlignedWindow]
                      ) -> tuple[np.ndarray, np.ndarray]:
    """(frame_idx (F,), T_world_cam (F, 4, 4)) of every frame posed by ``best`` or by the windows
    jointly aligned with it, sorted by frame; a frame two windows pose keeps ``best``'s pose."""
    group = best.info.get("group")
    chain = [best] + [w for w in windows if w is not best and group is not None
                      and w.info.get("group") == group]
    frame_idx, first = np.unique(np.concatenate([w.poses.frame_idx for w in chain]),
                                 return_index=True)
    return frame_idx, np.concatenate([w.T_world_cam for w in chain])[first]


def _chained_poses(track: SignTrack, best: AlignedWindow,
                   windows: list[AlignedWindow]) -> TrackPoses:
    """Poses of the track's frames from ``best`` and, for frames it did not pose, from the other
    windows jointly aligned with it (they agree on shared frames to millimetres, so a sign may
    span two windows of a chain)."""
    frame_idx, T_world_cam = _chain_trajectory(best, windows)
    keep = np.isin(track.frame_idx, frame_idx)
    rows = np.searchsorted(frame_idx, track.frame_idx[keep])
    return TrackPoses(keep, T_world_cam[rows], *_fit(best.info), best.info["rms_m"])
