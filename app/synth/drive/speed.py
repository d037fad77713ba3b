"""How far along the road the car is at any time: cruise speed, smooth speed variation and stops.

Everything is a function of time since the first frame, so frames and GPS fixes (taken at other
times) sample one and the same truth. The speed noise is drawn on a fixed time grid, so a profile
over a longer time extends a shorter one unchanged (the corpus sizes journeys with that).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from app.synth.drive.trajectory import smooth_noise

STEP_S = 0.005  # integration step: well under any frame or fix interval
NOISE_STEP_S = 0.05
SPEED_CORRELATION_S = 4.0  # how slowly the driver's speed wanders


@dataclass(frozen=True)
class SpeedProfile:
    """Arc length ``s_m(t)`` along the road, monotone non-decreasing."""

    start_m: float
    speed_mps: float  # cruise speed
    t_s: np.ndarray | None = None  # a fine grid; None: constant cruise speed
    offset_m: np.ndarray | None = None  # distance driven at each ``t_s``

    def s_at(self, t_s) -> np.ndarray:
        t = np.asarray(t_s, dtype=float)
        if self.t_s is None:
            return self.start_m + self.speed_mps * t
        return self.start_m + np.interp(t, self.t_s, self.offset_m)


def speed_profile(rng: np.random.Generator, start_m: float, speed_mps: float, duration_s: float,
                  variation: float = 0.0, stops: tuple[tuple[float, float], ...] = (),
                  decel_mps2: float = 2.0) -> SpeedProfile:
    """The car's progress over ``[0, duration_s]``.

    ``variation``: the speed is ``speed_mps * exp(variation * n(t))`` with n smooth unit noise.
    ``stops``: (t_rest_s, dwell_s) pairs: the car brakes at ``decel_mps2`` to stand still from
    t_rest_s for dwell_s, then accelerates back at the same rate (the speed is the minimum of the
    cruise speed and these braking/accelerating ramps).
    """
    if variation == 0.0 and not stops:
        return SpeedProfile(start_m, speed_mps)  # exactly start + v t, as before profiles existed
    n = int(math.ceil(duration_s / STEP_S)) + 2
    t = np.arange(n) * STEP_S
    v = np.full(n, float(speed_mps))
    if variation > 0.0:
        n_coarse = int(math.ceil(t[-1] / NOISE_STEP_S)) + 2
        noise = smooth_noise(rng, n_coarse, SPEED_CORRELATION_S / NOISE_STEP_S)[:, 0]
        v *= np.exp(variation * np.interp(t, np.arange(n_coarse) * NOISE_STEP_S, noise))
    for t_rest, dwell in stops:
        ramp = decel_mps2 * np.maximum(np.maximum(t_rest - t, t - t_rest - dwell), 0.0)
        v = np.minimum(v, ramp)
    offset = np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * STEP_S)])
    return SpeedProfile(start_m, speed_mps, t, offset)
