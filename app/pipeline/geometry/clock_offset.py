"""The dash cam's clock against the GPS's, from the journey's turns.

Times: ``t_video_s`` seconds since the video's first frame, ``t_gps_s`` seconds since the GPS log's
first fix; the offset is what is added to video time to get GPS time, ``t_gps = t_video + offset``.
Positions ``xy_enu`` (M, 2) are metres east and north in a local frame (``geometry.geodesy``).
Course is clockwise from north, radians (degrees in reasons). The image's sideways motion
``dx_px`` is positive to the right, so a right turn (course increasing) moves the scene left:
``dx ~ -f * dcourse``, f the focal length in pixels.

Method. A smoothing spline through the fixes gives the course wherever the car is faster than
MIN_SPEED_MPS (slower, the course is noise). The course and the images' cumulative turn are both
blurred by one Gaussian in time, so that their shapes stay alike however much the GPS noise needs
smoothing (blurring the positions alone, tried first, left the GPS turn blunter than the images'
and the offset up to 0.15 s out). For an offset d each image pair k (its frames at times
``t0_k, t1_k``) is predicted to move ``-f g_k(d) + b dt_k``, ``g_k`` the blurred course change from
``t0_k + d`` to ``t1_k + d``; where that course is unknown (off the log, too slow) g_k is 0, so an
offset pushing the images' turns off the log is not favoured and every offset is judged on the
same pairs. f (> 0) and b (what driving forward leaves in the images' motion, px/s; a prior
N(0, (DRIFT_RAD_S f)^2), so that a steady turn cannot hide in it) are fitted in closed form per
offset under a Huber loss; the offset is the best of a grid over prior -+ search, refined by a
bounded scalar search within REFINE_S of it on the pairs whose course is known all across that
span (so that no offset gains by bringing a pair onto the log). Its sigma is that of nonlinear
least squares in (d, f, b) from the Jacobian, the larger of the plain figure and Newey-West's
(residuals run on over seconds), plus the larger of what the fixes' noise (NOISE_DRAWS) and where
they fall (JACKKNIFE_GROUPS) move the match by, and a floor. A rival minimum counts only where f
is well above zero too. Each of SMOOTH_S is tried; of those whose course changes the fixes' noise
leaves clean (MAX_NOISE_SHARE), the smallest sigma wins. The measurements behind the choices:
docs/decisions/clock-offset-from-turns.md.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.integrate import cumulative_trapezoid
from scipy.interpolate import make_smoothing_spline
from scipy.ndimage import gaussian_filter1d, median_filter
from scipy.optimize import minimize_scalar

MIN_SPEED_MPS = 2.0
MIN_TURN_DEG = 30.0  # the largest course change within TURN_WINDOW_S, at speed, must reach this
TURN_WINDOW_S = 10.0
SMOOTH_S = (0.2, 0.3, 0.45, 0.7)  # Gaussian blurs (sigma, s) tried on both signals
MAX_CUTOFF_HZ = 1.0  # the position spline passes the path's motion below this (and below half
# the fix rate) and damps the fixes' noise above it
GRID_STEP_S = 0.1  # the coarse search; the objective is smooth over a turn's seconds
# The refinement searches this far either side of the best grid offset, on the pairs known all
# across it: three grid steps, room for the grid's best to sit a pair or two off (0.6 s measured:
# no better at 10 Hz, fewer pairs kept on a short clip).
REFINE_S = 3 * GRID_STEP_S
STEP_S = 0.02  # both signals are sampled this finely and interpolated linearly
HUBER_K = 2.5  # residuals beyond this many robust sigmas count linearly (a lost pair of frames)
IRLS_ITERATIONS = 3
OUTLIER_PAIRS = 11  # a pair is judged against the median of this many around it
LAG_S = 3.0  # Newey-West bandwidth beyond the blur's own reach (3 sigma)
# A second local minimum (further than SECOND_MIN_APART_S) within this many sigma^2 of the best
# makes the offset ambiguous: chi-square, scaled by the reported variance over the plain one (a
# rendered journey's 1 Hz fixes left a sidelobe at 48-77; one turn filmed, two alike logged: 2-24).
AMBIGUOUS_CHI2 = 36.0
SECOND_MIN_APART_S = 2.0
# What driving forward leaves at the centre column (b) is the focus of expansion's distance from
# it (mount yaw, principal point: up to ~0.05 f) times speed over the corners' depth (up to ~1/s):
# b's prior sigma is this times f, a turn rate no steady turn is as slow as (3 deg/s).
DRIFT_RAD_S = 0.05
MIN_SCALE_T = 5.0  # f must be this many of its sigmas above zero: the images see the GPS's turns
MAX_SIGMA_S = 1.0
MIN_PAIRS = 20
MIN_FIXES = 6  # the jackknife leaves one out of six, and a smoothing spline needs five
# The fixes' noise moves the course the images are matched against, and a turn or two gives the
# residuals too few independent stretches to tell: that share of sigma is found by matching again
# (linearised) against the course from the fixes with this many draws of their noise added.
NOISE_DRAWS = 8
# Where the fixes happen to fall on a turn (1 Hz: four or five on it) moves the spline's course
# more than their noise: a grouped jackknife (every JACKKNIFE_GROUPS-th fix left out in turn, the
# first and last always kept), linearised likewise, measures it; the larger of the two counts.
JACKKNIFE_GROUPS = 8
MAX_NOISE_SHARE = 0.1
# Beyond this the fixes' noise moves the course more than the turns do: whatever matches it is
# noise (a phone-like 5 Hz log, corpus c2006, matched 5.5 s off with f 64 px for a lens of 102).
MAX_NOISY_SHARE = 1.0
SIGMA_FLOOR_S = 0.01  # below what noise-free synthetic journeys are matched to (0.002-0.006 s)
_BLOCK = 64  # offsets evaluated together (memory: _BLOCK x K floats per array)


@dataclass(frozen=True)
class ClockOffset:
    """``offset_s`` to add to video time to get GPS time (None: not estimated, keep the prior);
    ``sigma_s`` its 1-sigma; ``reason`` one line for the journey's report."""

    offset_s: float | None
    sigma_s: float | None
    reason: str


@dataclass(frozen=True)
class _Course:
    """On the grid ``t_s`` (G,): course ``psi`` (rad, unwrapped along the fast samples) and
    ``fast`` (G,) bool, faster than MIN_SPEED_MPS."""

    t_s: np.ndarray
    psi: np.ndarray
    fast: np.ndarray


@dataclass(frozen=True)
class _Match:
    """One blur's answer, before it is judged (``_refusal``)."""

    offset_s: float
    sigma_s: float
    f_px: float
    f_sigma_px: float
    second_s: float | None  # a rival minimum's offset, None: none close
    at_edge: bool
    noise_share: float  # the fixes' noise in the course changes matched, over their power

    @staticmethod
    def none(offset_s: float, *, at_edge: bool = False) -> "_Match":
        """No fit at ``offset_s``: f 0 +- inf, refused as too little signal (or at the edge)."""
        return _Match(offset_s, np.inf, 0.0, np.inf, None, at_edge, np.inf)


def estimate_clock_offset(t_video_s: np.ndarray, dx_px: np.ndarray, t_gps_s: np.ndarray,
                          xy_enu: np.ndarray, *, prior_offset_s: float, search_s: float = 30.0,
                          dt_s: np.ndarray | None = None) -> ClockOffset:
    """The offset from image pairs at mid-times ``t_video_s`` (K,) moving ``dx_px`` (K,) (NaN:
    unmeasured) over ``dt_s`` (K,) (None: the spacing of the mid-times), against fixes at
    ``t_gps_s`` (M,) at ``xy_enu`` (M, 2). Searched over ``prior_offset_s`` -+ ``search_s``."""
    t_mid = np.asarray(t_video_s, float)
    dt = np.gradient(t_mid) if dt_s is None else np.asarray(dt_s, float)
    ok = np.isfinite(dx_px) & np.isfinite(t_mid) & (dt > 0)
    t_mid, dt, dx = t_mid[ok], dt[ok], np.asarray(dx_px, float)[ok]
    t_fix, xy_fix = _fixes(np.asarray(t_gps_s, float), np.asarray(xy_enu, float)[:, :2])
    if len(dx) < MIN_PAIRS or len(t_fix) < MIN_FIXES:
        return ClockOffset(None, None, f"too little to match: {len(dx)} image pairs measured, "
                                       f"{len(t_fix)} GPS fixes")
    course = _course(t_fix, xy_fix)
    lo, hi = prior_offset_s - search_s, prior_offset_s + search_s
    turn_deg = _largest_turn_deg(course, t_mid[0] - dt[0] + lo, t_mid[-1] + dt[-1] + hi)
    if turn_deg < MIN_TURN_DEG:
        return ClockOffset(None, None, f"no turn to match: the GPS course changes at most "
                                       f"{turn_deg:.0f} deg in {TURN_WINDOW_S:.0f} s at over "
                                       f"{MIN_SPEED_MPS:.0f} m/s ({MIN_TURN_DEG:.0f} needed)")
    ends = (t_mid - 0.5 * dt, t_mid + 0.5 * dt)
    grid = prior_offset_s + np.arange(-search_s, search_s + 0.5 * GRID_STEP_S, GRID_STEP_S)
    noise_m = _fix_noise_m(xy_fix)
    rng = np.random.default_rng(0)  # the same journey always gets the same sigma
    draws = [_course(t_fix, xy_fix + rng.normal(0.0, noise_m, xy_fix.shape))
             for _ in range(NOISE_DRAWS)]
    n = np.arange(len(t_fix))
    knives = [_course(t_fix[keep], xy_fix[keep]) for keep in
              ((n % JACKKNIFE_GROUPS != j) | (n == 0) | (n == n[-1])
               for j in range(JACKKNIFE_GROUPS))]
    matches = [_match(course, draws, knives, ends, dx, grid, s) for s in SMOOTH_S]
    good = [m for m in matches if _refusal(m, prior_offset_s) is None]
    # A blur that leaves the course changes noisy fits a shrunken f and claims a small sigma
    # (10 min, 0.5 m fixes at 10 Hz: f 90 px of 700 at the least blur): the least blur whose
    # noise share is small is preferred; the most blurred when none is.
    clean = [m for m in good if m.noise_share < MAX_NOISE_SHARE]
    good = clean or good[-1:]
    if not good:
        return ClockOffset(None, None, _refusal(min(matches, key=lambda m: m.sigma_s),
                                                prior_offset_s))
    m = min(good, key=lambda m: m.sigma_s)
    return ClockOffset(m.offset_s, m.sigma_s,
                       f"from the turns ({turn_deg:.0f} deg at most in {TURN_WINDOW_S:.0f} s): "
                       f"{m.offset_s:+.2f} s +- {m.sigma_s:.2f} s, "
                       f"{m.offset_s - prior_offset_s:+.2f} s from the camera's clock; "
                       f"f {m.f_px:.0f} px")


def _refusal(m: _Match, prior_offset_s: float) -> str | None:
    if m.at_edge:
        return (f"the best match lies at the edge of the search ({m.offset_s:+.1f} s, prior "
                f"{prior_offset_s:+.1f} s)")
    if not m.f_px > MIN_SCALE_T * m.f_sigma_px:
        return (f"too little signal: the images' motion does not follow the GPS turns (scale "
                f"{m.f_px:.0f} +- {m.f_sigma_px:.0f} px)")
    if m.noise_share > MAX_NOISY_SHARE:
        return (f"the GPS course is mostly noise: the fixes' noise changes it "
                f"{m.noise_share:.1f}x as much as the turns do")
    if m.second_s is not None:
        return (f"ambiguous: {m.second_s:+.1f} s fits nearly as well as {m.offset_s:+.2f} s "
                f"(prior {prior_offset_s:+.1f} s)")
    if m.sigma_s > MAX_SIGMA_S:
        return (f"too uncertain: {m.offset_s:+.2f} s +- {m.sigma_s:.2f} s (at most "
                f"{MAX_SIGMA_S:.1f} s)")
    return None


def _fixes(t_gps_s: np.ndarray, xy_enu: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The fixes in time order, one per time, with a position."""
    order = np.argsort(t_gps_s, kind="stable")
    t, xy = t_gps_s[order], xy_enu[order]
    keep = np.r_[True, np.diff(t) > 0] & np.all(np.isfinite(xy), axis=1)
    return t[keep], xy[keep]


def _fix_noise_m(xy: np.ndarray) -> float:
    """White noise (m, per axis) of the fixes: each fix against the quadratic through it and its
    two neighbours either side (Savitzky-Golay, even spacing assumed), the median absolute
    residual scaled for a Gaussian; the turns are few enough for the median to ignore them."""
    if len(xy) < 5:
        return 0.0
    smooth = (np.array([-3, 12, 17, 12, -3]) / 35.0)[:, None, None]
    resid = xy[2:-2] - sum(smooth[k] * xy[k:len(xy) - 4 + k] for k in range(5))
    return float(np.median(np.abs(resid)) / 0.6745 / np.sqrt(18 / 35))


def _course(t: np.ndarray, xy: np.ndarray) -> _Course:
    rate_hz = (len(t) - 1) / max(t[-1] - t[0], 1e-9)
    # The penalised fit passes angular frequencies below (rate / lam) ** (1/4) and damps above.
    lam = rate_hz / (2 * np.pi * min(MAX_CUTOFF_HZ, 0.5 * rate_hz)) ** 4
    splines = [make_smoothing_spline(t, xy[:, k], lam=lam) for k in (0, 1)]
    grid = np.arange(t[0], t[-1] + 0.5 * STEP_S, STEP_S)
    v_e, v_n = (s.derivative()(grid) for s in splines)
    fast = np.hypot(v_e, v_n) > MIN_SPEED_MPS
    psi = np.arctan2(v_e, v_n)
    # Unwrapped along the fast samples only: a stop's noisy course must not add a turn of 2 pi.
    psi[fast] = np.unwrap(psi[fast])
    return _Course(grid, psi, fast)


def _largest_turn_deg(course: _Course, t_from_s: float, t_to_s: float) -> float:
    """Largest |course change| between two times at most TURN_WINDOW_S apart with the car at
    speed between them, within the times: the course's range over each such span, not its
    end-to-end change, which an S-bend (left, then right) nets to nearly nothing. A stop splits
    the course into runs; a turn between two stops counts."""
    inside = (course.t_s >= t_from_s) & (course.t_s <= t_to_s)
    psi, fast = course.psi[inside], course.fast[inside]
    n = int(round(TURN_WINDOW_S / STEP_S)) + 1
    edges = np.flatnonzero(np.diff(np.r_[0, fast.astype(np.int8), 0]))
    largest = 0.0
    for start, stop in zip(edges[::2], edges[1::2]):  # runs of samples at speed
        run = psi[start:stop]
        if len(run) > 1:
            spans = np.lib.stride_tricks.sliding_window_view(run, min(n, len(run)))
            largest = max(largest, float(np.ptp(spans, axis=1).max()))
    return float(np.degrees(largest))


def _blurred_course(course: _Course, smooth_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Course blurred over the fast samples only, and where it is known (G,) bool."""
    sigma = smooth_s / STEP_S
    weight = gaussian_filter1d(course.fast.astype(float), sigma, mode="constant")
    psi = gaussian_filter1d(np.where(course.fast, course.psi, 0.0), sigma, mode="constant")
    known = course.fast & (weight > 0.9)  # mostly fast samples around it, not an end
    return psi / np.maximum(weight, 1e-12), known


def _blurred_dx(ends: tuple[np.ndarray, np.ndarray], dx: np.ndarray, smooth_s: float
                ) -> np.ndarray:
    """(K,) each pair's motion after blurring the images' cumulative motion like the course."""
    t0, t1 = ends
    # A pair far off its neighbours (a passing lorry filling the view) is clipped first: the blur
    # would spread it where the Huber loss could no longer tell it.
    typical = median_filter(dx, size=OUTLIER_PAIRS, mode="nearest")
    spread = max(1.4826 * float(np.median(np.abs(dx - typical))), 1e-9)
    dx = typical + np.clip(dx - typical, -HUBER_K * spread, HUBER_K * spread)
    u = np.arange(t0[0], t1[-1] + 0.5 * STEP_S, STEP_S)
    rate = np.interp(u, 0.5 * (t0 + t1), dx / (t1 - t0))  # px/s; a lost pair: its neighbours'
    # Trapezoids: a plain running sum would put each sample's motion a half step early.
    cum = gaussian_filter1d(cumulative_trapezoid(rate, dx=STEP_S, initial=0.0),
                            smooth_s / STEP_S, mode="nearest")
    out = np.interp(t1, u, cum) - np.interp(t0, u, cum)
    # Near the video's ends the blur lacks the motion beyond them, which the course's has.
    reach = 3.0 * smooth_s
    return np.where((t0 >= u[0] + reach) & (t1 <= u[-1] - reach), out, np.nan)


def _increments(course: _Course, smooth_s: float, ends, offsets: np.ndarray) -> np.ndarray:
    """(D, K) blurred course change over each pair's times plus each offset; 0 where unknown."""
    change, ok = _course_changes(course, smooth_s, ends, offsets)
    return np.where(ok, change, 0.0)


def _course_changes(course: _Course, smooth_s: float, ends, offsets: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray]:
    """(D, K) blurred course change over each pair's times plus each offset, and (D, K) bool
    where it is known."""
    psi, known = _blurred_course(course, smooth_s)
    t0, t1 = ends[0][None, :] + offsets[:, None], ends[1][None, :] + offsets[:, None]
    ok = (np.interp(t0, course.t_s, known.astype(float), left=0, right=0) == 1) & \
         (np.interp(t1, course.t_s, known.astype(float), left=0, right=0) == 1)
    return np.interp(t1, course.t_s, psi) - np.interp(t0, course.t_s, psi), ok


def _match(course: _Course, draws: list[_Course], knives: list[_Course], ends,
           dx_raw: np.ndarray, grid: np.ndarray, smooth_s: float) -> _Match:
    dx = _blurred_dx(ends, dx_raw, smooth_s)
    inner = np.isfinite(dx)
    if inner.sum() < MIN_PAIRS:  # a clip too short for this blur's reach
        return _Match.none(float(grid[len(grid) // 2]))
    ends, dx = (ends[0][inner], ends[1][inner]), dx[inner]
    dt = ends[1] - ends[0]
    every = np.ones(len(dx), bool)

    def fit(offsets: np.ndarray, scale: float | None, pairs: np.ndarray = every):
        on = (ends[0][pairs], ends[1][pairs])
        parts = [_fit_block(-_increments(course, smooth_s, on, offsets[i:i + _BLOCK]),
                            dt[pairs], dx[pairs], scale, drift_px_s)
                 for i in range(0, len(offsets), _BLOCK)]
        return [np.concatenate(p) for p in zip(*parts)]

    # The Huber scale: the residual's median absolute value where least squares fits best; the
    # drift's prior sigma from the f fitted there (none if the images turn against the GPS).
    drift_px_s = np.inf
    loss, f, _, _, resid = fit(grid, None)
    at = int(np.argmin(loss))
    scale = max(1.4826 * float(np.median(np.abs(resid[at]))), 1e-9)
    drift_px_s = DRIFT_RAD_S * float(f[at]) if f[at] > 0 else np.inf
    loss = fit(grid, scale)[0]
    at = int(np.argmin(loss))
    if at in (0, len(grid) - 1):
        return _Match.none(float(grid[at]), at_edge=True)
    # Near the best grid offset every offset is judged on the same pairs, those whose course is
    # known all across the refinement: a pair stepping onto the log lowers the loss by itself,
    # and where the video outlasts the log inside a turn the refinement (and the Jacobian) sat
    # on such a step, a whole pair's worth early (docs/decisions/clock-offset-from-turns.md).
    lo, hi = grid[at] - REFINE_S, grid[at] + REFINE_S
    same = _course_changes(course, smooth_s, ends,
                           np.arange(lo - STEP_S, hi + 1.5 * STEP_S, STEP_S))[1].all(axis=0)
    if same.sum() < MIN_PAIRS:
        return _Match.none(float(grid[at]))
    best = minimize_scalar(lambda d: fit(np.array([d]), scale, same)[0][0], bounds=(lo, hi),
                           method="bounded", options={"xatol": 1e-4})
    offset = float(best.x)
    lags = int(round((LAG_S + 3 * smooth_s) / max(float(np.median(dt)), 1e-9)))

    def solve(d: float, pairs: np.ndarray):
        """At offset ``d`` on ``pairs``: loss, f, w, r, the course changes, the Jacobian and the
        covariances (plain, lagged)."""
        loss_d, f_d, _, w_d, r_d = (v[0] for v in fit(np.array([d]), scale, pairs))
        on = (ends[0][pairs], ends[1][pairs])
        (c_d, c_lo, c_hi), (ok_d, _, _) = _course_changes(course, smooth_s, on,
                                                           np.array([d, d - STEP_S, d + STEP_S]))
        g_d = np.where(ok_d, c_d, 0.0)
        # The derivative holds each pair's known-ness at d: a pair stepping onto the log within
        # the difference (0 -> its whole course change) is no slope, and read as one it made a
        # single pair look 7x as sensitive and sigma 6x too small (KITTI turn at 1 Hz).
        slope = np.where(ok_d, (c_hi - c_lo) / (2 * STEP_S), 0.0)
        # Columns: d/d offset, d/d f, d/d b of the prediction -f g + b dt.
        jac_d = np.column_stack([-f_d * slope, -g_d, dt[pairs]])
        return (loss_d, f_d, w_d, r_d, g_d, jac_d) + _covariances(jac_d, w_d, r_d, lags,
                                                                  drift_px_s)

    _, f, w, r, g, jac, plain, lagged = solve(offset, same)
    on = (ends[0][same], ends[1][same])
    # Each draw's course moves the prediction by -f dg: the fit answers with gain @ (f dg).
    prior = np.diag([0.0, 0.0, (scale / drift_px_s) ** 2])
    gain = np.linalg.pinv(jac.T @ (w[:, None] * jac) + prior) @ (jac * w[:, None]).T
    dg = [_increments(d, smooth_s, on, np.array([offset]))[0] - g for d in draws]
    gps_var = float(np.mean([(gain[0] @ (f * e)) ** 2 for e in dg])) if dg else 0.0
    noise_share = float(np.mean([e @ e for e in dg]) / max(g @ g, 1e-300)) if dg else 0.0
    shifts = [gain[0] @ (f * (_increments(k, smooth_s, on, np.array([offset]))[0] - g))
              for k in knives]
    jack_var = (len(shifts) - 1) / len(shifts) * float(np.sum((shifts - np.mean(shifts)) ** 2))
    sigma = float(np.sqrt(max(plain[0, 0], lagged[0, 0]) + max(gps_var, jack_var)
                          + SIGMA_FLOOR_S ** 2))
    inflation = max(sigma ** 2 / max(plain[0, 0], 1e-300), 1.0)
    # Rivals are judged on the grid's terms: every pair, against the grid's best.
    best_loss = min(loss[at], fit(np.array([offset]), scale)[0][0])
    rival = None
    for second in _minima(grid, loss, offset):
        if (loss[second] - best_loss) / inflation >= AMBIGUOUS_CHI2:
            break
        # A rival must be a match too: the scene turning with the GPS, f well above zero.
        there = solve(float(grid[second]), every)
        if there[1] > MIN_SCALE_T * np.sqrt(max(there[6][1, 1], there[7][1, 1])):
            rival = float(grid[second])
            break
    return _Match(offset, sigma, float(f), float(np.sqrt(max(plain[1, 1], lagged[1, 1]))),
                  rival, False, noise_share)


def _fit_block(x: np.ndarray, dt: np.ndarray, dx: np.ndarray, scale: float | None,
               drift_px_s: float = np.inf):
    """Per offset (rows of ``x`` (D, K), the regressor -g): ``dx ~ f x + b dt`` by least
    squares (``scale`` None; loss = RSS) or Huber with ``scale`` (px) by reweighting (loss in
    scale^2, plus b's prior N(0, ``drift_px_s``^2)). Returns loss (D,), f (D,), b (D,), weights
    (D, K), residuals (D, K)."""
    w = np.ones_like(x)
    ridge = 0.0 if scale is None else (scale / drift_px_s) ** 2
    for _ in range(1 if scale is None else IRLS_ITERATIONS + 1):
        sxx, sxd, sdd = (w * x * x).sum(1), (w * x * dt).sum(1), (w * dt * dt).sum(1) + ridge
        sxy, sdy = (w * x * dx).sum(1), (w * dt * dx).sum(1)
        det = sxx * sdd - sxd ** 2
        flat = det <= 1e-12 * np.maximum(sxx * sdd, 1e-300)  # no turn in reach of this offset
        f = np.where(flat, 0.0, (sdd * sxy - sxd * sdy) / np.where(flat, 1.0, det))
        b = (sdy - f * sxd) / sdd
        r = dx - f[:, None] * x - b[:, None] * dt
        if scale is None:
            return (r * r).sum(1), f, b, w, r
        w = np.minimum(1.0, HUBER_K * scale / np.maximum(np.abs(r), 1e-300))
    u = np.abs(r) / scale
    loss = np.where(u <= HUBER_K, u * u, 2 * HUBER_K * u - HUBER_K ** 2).sum(1)
    return loss + (b / drift_px_s) ** 2, f, b, w, r


def _covariances(jac: np.ndarray, w: np.ndarray, r: np.ndarray, lags: int, drift_px_s: float
                 ) -> tuple[np.ndarray, np.ndarray]:
    """(3, 3) parameter covariances, b's prior included: plain (white residuals) and Newey-West
    (Bartlett weights over ``lags`` pairs)."""
    var = float(np.sum(w * r * r) / max(len(r) - 3, 1))
    a_inv = np.linalg.pinv(jac.T @ (w[:, None] * jac) + np.diag([0, 0, var / drift_px_s ** 2]))
    plain = var * a_inv
    score = (w * r)[:, None] * jac  # each pair's share of the gradient
    meat = score.T @ score
    for lag in range(1, min(lags, len(r) - 1) + 1):
        c = score[lag:].T @ score[:-lag]
        meat += (1 - lag / (lags + 1)) * (c + c.T)
    return plain, a_inv @ meat @ a_inv


def _minima(grid: np.ndarray, loss: np.ndarray, offset: float) -> np.ndarray:
    """Indices of the local minima of ``loss`` on ``grid`` away from ``offset``, lowest first."""
    inner = np.arange(1, len(grid) - 1)
    minima = inner[(loss[inner] <= loss[inner - 1]) & (loss[inner] <= loss[inner + 1])]
    minima = minima[np.abs(grid[minima] - offset) > SECOND_MIN_APART_S]
    return minima[np.argsort(loss[minima], kind="stable")]
