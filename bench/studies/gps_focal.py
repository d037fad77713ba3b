"""Can the GPS check the focal length? ``signmap bench gps-focal`` (a study; nothing in the
pipeline uses it: docs/decisions/gps-focal-check.md says why).

A focal length short by a factor 1/kappa makes every rotation the reconstruction sees about kappa
times too large (an image offset x is read as the angle atan(x / f)): with fx 3 % short, tuning
journey c0054's 85.5 deg turn came out as 87.9 deg. The trajectory then bends too far and fits
the GPS worse, which no choice of similarity hides. So each turning ego-motion window is unbent
by candidate factors kappa (its rotations relative to its first camera divided by kappa, its
steps between cameras re-chained along them), aligned to the GPS by a similarity, and the kappa
that fits best over a journey's turning windows estimates the focal error: fx_true ~ kappa * fx.
The same fit against the true camera centres says how much of the error is the ego-motion's and
how much the GPS's.

Frames: ``model`` is each window's own reconstruction frame (``ego_motion.WindowPoses``),
``xyz`` metric positions of the journey's frames (GPS or truth, any ENU-like frame).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from app.pipeline.geometry.similarity import umeyama
from app.pipeline.steps.align import fit_rows
from app.pipeline.steps.calibrate import rotation_covered_deg
from app.pipeline.steps.ego_motion import WindowPoses

# Candidate rotation scales: +-8 % covers what the calibration gates let through (3 %) twice over.
KAPPAS = np.round(np.arange(0.92, 1.0801, 0.0025), 4)


def unbent_centres(T_model_cam: np.ndarray, kappa: float) -> np.ndarray:
    """(K, 3) camera centres of the poses ``T_model_cam`` (K, 4, 4) with every rotation relative to
    the first camera divided by ``kappa``, each step between consecutive centres kept as it was in
    the camera it starts from (forward motion stays forward motion)."""
    R_model_cam = T_model_cam[:, :3, :3]
    c_model = T_model_cam[:, :3, 3]
    R0 = R_model_cam[0]
    rotvec_rel = Rotation.from_matrix(np.einsum("ji,njk->nik", R0, R_model_cam)).as_rotvec()
    R_unbent = R0 @ Rotation.from_rotvec(rotvec_rel / kappa).as_matrix()
    step_cam = np.einsum("nji,nj->ni", R_model_cam[:-1], np.diff(c_model, axis=0))
    step_unbent = np.einsum("nij,nj->ni", R_unbent[:-1], step_cam)
    return np.vstack([c_model[:1], c_model[:1] + np.cumsum(step_unbent, axis=0)])


def _sse_m2(c_model: np.ndarray, xyz: np.ndarray) -> float:
    sim = umeyama(c_model, xyz)
    return float(np.sum((sim.apply(c_model) - xyz) ** 2))


@dataclass(frozen=True)
class FocalEvidence:
    """``kappa`` the rotation scale that fits best (the focal length times ``kappa`` fits best),
    ``kappa_std`` its standard error from the fit's curvature and residual; ``rms_m`` the
    windows' pooled alignment residual as run (kappa 1), ``rms_best_m`` unbent by ``kappa``;
    ``n_windows`` and ``turn_deg`` (their summed rotation): how much evidence there is."""

    kappa: float
    kappa_std: float
    n_windows: int
    turn_deg: float
    rms_m: float
    rms_best_m: float


@dataclass(frozen=True)
class WindowCurve:
    """One turning window's evidence: ``sse_m2`` (len(kappas),) its alignment's sum of squared
    residuals unbent by each candidate kappa; ``dof`` the residual's degrees of freedom (two
    per GPS fix in its span when the fix times are known: the frames between fixes share their
    errors); ``turn_deg`` its rotation."""

    window: tuple[int, int]
    turn_deg: float
    n_rows: int
    dof: int
    sse_m2: np.ndarray


def window_curves(poses: list[WindowPoses], xyz_gps: np.ndarray,
                  trusted: np.ndarray | None = None, *, min_turn_deg: float = 30.0,
                  t_frame_s: np.ndarray | None = None, t_fix_s: np.ndarray | None = None,
                  kappas: np.ndarray = KAPPAS) -> list[WindowCurve]:
    """The evidence of each window of ``poses`` turning at least ``min_turn_deg``, against
    ``xyz_gps`` (N, 3) at the frames ``trusted`` (N,) bool marks (None: all). ``t_frame_s`` (N,)
    and ``t_fix_s`` (M,): frame and GPS fix times, to count the independent GPS positions."""
    out = []
    for p in poses:
        turn = rotation_covered_deg(p.T_model_cam)
        use = fit_rows(p.frame_idx, trusted)
        if turn < min_turn_deg or use.sum() < 6:
            continue
        xyz = xyz_gps[p.frame_idx]
        try:
            # Unbend over all frames (the chain needs every step), fit on the trusted ones.
            sse = np.array([_sse_m2(unbent_centres(p.T_model_cam, kappa)[use], xyz[use])
                            for kappa in kappas])
        except ValueError:  # the GPS positions do not fix a similarity (the car stood still)
            continue
        rows = int(use.sum())
        if t_frame_s is not None and t_fix_s is not None:
            t = t_frame_s[p.frame_idx[use]]
            n_fixes = int(np.count_nonzero((t_fix_s >= t.min()) & (t_fix_s <= t.max())))
            dof = 2 * min(n_fixes, rows) - 7
        else:
            dof = 3 * rows - 7
        out.append(WindowCurve(p.window, turn, rows, max(dof, 1), sse))
    return out


def focal_evidence(poses: list[WindowPoses], xyz_gps: np.ndarray,
                   trusted: np.ndarray | None = None, *, min_turn_deg: float = 30.0,
                   t_frame_s: np.ndarray | None = None, t_fix_s: np.ndarray | None = None,
                   kappas: np.ndarray = KAPPAS) -> FocalEvidence | None:
    """The rotation scale that best fits the turning windows of ``poses`` (``window_curves``,
    same arguments) to the GPS together; None when no window turns ``min_turn_deg``."""
    curves = window_curves(poses, xyz_gps, trusted, min_turn_deg=min_turn_deg,
                           t_frame_s=t_frame_s, t_fix_s=t_fix_s, kappas=kappas)
    return combine(curves, kappas)


def combine(curves: list[WindowCurve], kappas: np.ndarray = KAPPAS) -> FocalEvidence | None:
    """The kappa minimising the windows' summed squared residuals, its standard error from the
    sum's curvature and residual variance; None for no window."""
    if not curves:
        return None
    sse = np.sum([c.sse_m2 for c in curves], axis=0)
    n_rows = sum(c.n_rows for c in curves)
    k = int(np.argmin(sse))
    kappa, curvature = float(kappas[k]), np.inf
    if 0 < k < len(kappas) - 1:
        # A parabola through the minimum and its neighbours: its vertex and curvature.
        a, b, _ = np.polyfit(kappas[k - 1:k + 2], sse[k - 1:k + 2], 2)
        if a > 0:
            kappa, curvature = float(-b / (2 * a)), float(a)
    # Each window's similarity takes 7 degrees of freedom (in its dof), kappa one more. Rows
    # repeat each independent GPS error n_rows / dof times over, which cancels between the
    # residual variance per row (sse / n_rows) and the inflation of the fit's variance (n_rows /
    # dof): var = sse / (curvature * dof).
    dof = max(sum(c.dof for c in curves) - 1, 1)
    kappa_std = float(np.sqrt(sse[k] / (curvature * dof))) if np.isfinite(curvature) else np.inf
    at_one = int(np.argmin(np.abs(kappas - 1.0)))
    return FocalEvidence(kappa=kappa, kappa_std=kappa_std, n_windows=len(curves),
                         turn_deg=float(sum(c.turn_deg for c in curves)),
                         rms_m=float(np.sqrt(sse[at_one] / n_rows)),
                         rms_best_m=float(np.sqrt(sse[k] / n_rows)))


@dataclass(frozen=True)
class JourneyFocal:
    """One kept journey: ``kappa_true`` = true fx / fx it ran with; ``gps`` the estimate against
    its smoothed GPS positions, ``truth`` against the true camera centres (None: no turning
    window)."""

    run: str
    name: str
    gps_kind: str
    gps_white_m: float
    gps_rate_hz: float
    kappa_true: float
    gps: FocalEvidence | None
    truth: FocalEvidence | None


def collect(replay_dirs: list[Path], corpus_dir: Path) -> list[JourneyFocal]:
    """The focal check of every journey kept in ``replay_dirs`` (``bench corpus
    --keep-reconstructions``), its truth read from ``corpus_dir``."""
    from app.pipeline.config import PipelineConfig
    from app.pipeline.run import gps_trusted
    from bench.corpus import replay

    rows = []
    for directory in replay_dirs:
        for path in sorted(Path(directory).glob("*.pkl")):
            kept = replay.load(path)
            recon, journey = kept["recon"], kept["journey"]
            if recon is None or not recon.poses:
                continue
            truth = json.loads((Path(corpus_dir) / path.stem / "truth.json").read_text())
            xyz_true = np.array([np.asarray(f["T_world_cam"])[:3, 3] for f in truth["frames"]])
            t_frame_s = journey.timestamps_s
            t_fix_s = None if journey.gps_fixes is None else journey.gps_fixes.timestamp_s
            gps = focal_evidence(recon.poses, recon.xyz_align,
                                 gps_trusted(journey, PipelineConfig(**kept["config"])),
                                 t_frame_s=t_frame_s, t_fix_s=t_fix_s)
            params = truth["corpus"]["params"]
            rows.append(JourneyFocal(
                Path(directory).name, path.stem, params["gps_kind"],
                params["gps_white_sigma_m"], params["gps_rate_hz"],
                truth["camera"]["fx"] / recon.calib.camera.fx, gps,
                focal_evidence(recon.poses, xyz_true)))
    return rows


def table(rows: list[JourneyFocal]) -> str:
    """Per journey, then per run and GPS kind: how far the GPS's kappa is from the true one."""
    lines = ["| run | journey | GPS | true kappa | from GPS | z | windows, deg "
             "| from true centres |",
             "| --- | --- | --- | --- | --- | --- | --- | --- |"]
    for r in rows:
        if r.gps is None:
            continue
        g, t = r.gps, r.truth
        z = (g.kappa - r.kappa_true) / g.kappa_std if np.isfinite(g.kappa_std) else np.nan
        lines.append(f"| {r.run} | {r.name} | {r.gps_kind} {r.gps_white_m:.2f} m "
                     f"{r.gps_rate_hz:g} Hz | {r.kappa_true:.4f} | {g.kappa:.4f} ± "
                     f"{g.kappa_std:.4f} | {z:+.1f} | {g.n_windows}, {g.turn_deg:.0f} | "
                     f"{t.kappa:.4f} |")
    lines += ["", "| run | GPS | journeys | \\|error\\| median / p90 | from true centres "
              "median / p90 | \\|z\\| < 2 |", "| --- | --- | --- | --- | --- | --- |"]
    for run in sorted({r.run for r in rows}):
        for kind in ("oxts", "phone"):
            sel = [r for r in rows if r.run == run and r.gps_kind == kind and r.gps is not None]
            if not sel:
                continue
            err = np.abs([r.gps.kappa - r.kappa_true for r in sel])
            err_t = np.abs([r.truth.kappa - r.kappa_true for r in sel])
            z = np.abs([(r.gps.kappa - r.kappa_true) / r.gps.kappa_std for r in sel])
            lines.append(f"| {run} | {kind} | {len(sel)} | {100 * np.median(err):.2f} / "
                         f"{100 * np.percentile(err, 90):.2f} % | {100 * np.median(err_t):.2f} / "
                         f"{100 * np.percentile(err_t, 90):.2f} % | {np.mean(z < 2):.0%} |")
    return "\n".join(lines)


def gps_heading_deg(xyz_gps: np.ndarray, timestamp_s: np.ndarray, cfg) -> np.ndarray:
    """(N,) signed heading (degrees, unwrapped) of each frame on the GPS track as the turn finder
    sees it (``plan``'s smoothing, then ``turns.heading_deg``)."""
    from app.pipeline.steps import turns

    xy_m = turns.smooth_track(xyz_gps[:, :2], timestamp_s, cfg.turn_smoothing_s,
                              cfg.turn_smoothing_max_m)
    return turns.heading_deg(xy_m, turns.track_length_m(xy_m, tolerance_m=cfg.rdp_tolerance_m))


def window_rotation_table(records_path: Path, corpus_dir: Path) -> str:
    """Per accepted self-calibration of a ``bench corpus`` run: its window's reconstructed
    rotation beside the range of the GPS heading over the window's frames."""
    import tempfile

    from app.pipeline.bundle.read import read_bundle
    from app.pipeline.config import PipelineConfig
    from app.pipeline.geometry import geodesy
    from app.pipeline.steps import turns

    cfg = PipelineConfig()
    lines = ["| journey | GPS | fx % | reconstructed ° | GPS heading range ° | ratio "
             "| 10 m chords at the ends ° | ratio |",
             "| --- | --- | --- | --- | --- | --- | --- | --- |"]
    for line in Path(records_path).read_text().splitlines():
        r = json.loads(line)
        cal = r.get("calibration") or {}
        if r.get("kind") != "journey" or cal.get("source") != "self":
            continue
        with tempfile.TemporaryDirectory() as tmp:
            journey = read_bundle(Path(corpus_dir) / r["name"] / "bundle.zip", Path(tmp))
        origin = geodesy.frame_at(journey.lat_deg[0], journey.lon_deg[0], None, cfg.metric_frame)
        xyz_gps = origin.to_local(journey.lat_deg, journey.lon_deg, None)
        heading = gps_heading_deg(xyz_gps, journey.timestamps_s,
                                  cfg)
        a, b = cal["windows"][0]
        gps_deg = float(np.max(np.abs(heading[a:b] - heading[a])))
        s_m = turns.track_length_m(xyz_gps[:, :2], tolerance_m=cfg.rdp_tolerance_m)
        chord_deg = turns.chord_rotation_deg(xyz_gps[:, :2], s_m, np.array([a, b - 1]), 10.0)
        p = r["params"]
        lines.append(f"| {r['name']} | {p['gps_kind']} {p['gps_white_sigma_m']:.2f} m | "
                     f"{cal['errors']['fx_pct']:+.2f} | {cal['rotation_deg']:.1f} | "
                     f"{gps_deg:.1f} | {cal['rotation_deg'] / max(gps_deg, 1e-6):.2f} | "
                     f"{chord_deg:.1f} | {cal['rotation_deg'] / max(chord_deg, 1e-6):.2f} |")
    return "\n".join(lines)
