"""How far a placed sign may be from where it really is: its covariance in the journey's ENU frame
(metres), the triangulation's own plus what georeferencing adds.

The triangulation covariance (``triangulation``) counts only the pixel noise of the
detections on fixed poses: a few centimetres, while the real errors are tenths of a metre. The
sign inherits the error of the window alignment that placed its poses: the GPS noise the Umeyama
fit averages (``alignment_rms_m`` over ``n`` fixes) and the part of the GPS error it cannot
average because it is common to the whole window (a receiver's slowly drifting bias, multipath
along a street): ``georef_floor_m`` per horizontal axis, plus ``bias_quad_per_m`` times the square of the
alignment's own residual RMS, twice that vertically (GPS
altitude is about twice as noisy). The square term is there because the common error grows faster
than the scatter: a 0.3 m receiver wanders by a few centimetres more than its alignment shows, a
2-3 m phone by metres (a term linear in the residual cannot fit both on the corpus, and fitted to 0 beside the
square: docs/decisions/sign-georef-bias-ratio.md). The
common part cannot be seen inside one window, but it grows with the receiver's noise (and when the
bundle states the receiver's accuracy, the floor is at least that: ``georef_floor_m``): on the
corpus, journeys whose fixes scatter by 2 m also wander by metres (phones, multipath), while an
OXTS-like receiver's 0.3 m comes with a bias of tenths. All enter as an isotropic term; the floor,
the square term and the gain on the averaged noise are knobs of ``PipelineConfig`` chosen on the
corpus's tuning half (docs/decisions/sign-uncertainty.md).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import brentq
from scipy.special import erf


@dataclass(frozen=True)
class GeorefTerms:
    """What the window alignments add to a sign's error, before the knobs weigh it: the averaged
    GPS noise ``sum w_i^2 rms_i^2 / n_i`` (m^2), the weight ``sum w_i^2`` of the floor and the
    residual ``sum w_i^2 rms_i^2`` (m^2), over the passes ``i`` combined with weights ``w_i`` (one
    pass: ``rms^2 / n``, 1 and ``rms^2``)."""

    averaged_noise_m2: float
    floor_weight: float
    residual_m2: float = 0.0

    @staticmethod
    def of_alignment(alignment_rms_m: float, n_fixes: int,
                     window_rms_m: float | None = None) -> "GeorefTerms":
        """The terms of one alignment over ``n_fixes`` fixes; ``window_rms_m``: the residual of
        the window (or chain) alignment when the sign's own alignment was fitted again over the
        frames by the sign (``alignment`` short or local), whose small residual would hide the
        bias it followed."""
        residual_m = alignment_rms_m if window_rms_m is None else window_rms_m
        return GeorefTerms(alignment_rms_m**2 / max(n_fixes, 1), 1.0, residual_m**2)

    def horizontal_m2(self, floor_m: float, noise_gain: float,
                      bias_quad_per_m: float = 0.0) -> float:
        """Variance per horizontal axis (m^2) these terms add, weighed by the knobs
        (``georef_horizontal_m2``)."""
        return float(georef_horizontal_m2(self.averaged_noise_m2, self.floor_weight,
                                          self.residual_m2, floor_m, noise_gain,
                                          bias_quad_per_m))

    def cov_m2(self, floor_m: float, noise_gain: float,
               bias_quad_per_m: float = 0.0) -> np.ndarray:
        """(3, 3) ENU covariance; altitude counts twice the horizontal error."""
        h = self.horizontal_m2(floor_m, noise_gain, bias_quad_per_m)
        return np.diag([h, h, 4.0 * h])


def georef_horizontal_m2(averaged_noise_m2, floor_weight, residual_m2, floor_m: float,
                         noise_gain: float, bias_quad_per_m: float):
    """Variance per horizontal axis (m^2) of ``GeorefTerms`` fields (scalars, or arrays of many
    signs' terms, as the bench's knob fit passes them) weighed by the
    knobs. The common error of a pass with residual ``r`` is ``bias_quad_per_m * r^2``; over several passes ``r`` is their weighted RMS residual (exact when they agree)."""
    floor_weight = np.asarray(floor_weight, float)
    residual_m2 = np.asarray(residual_m2, float)
    rms_m = np.sqrt(np.divide(residual_m2, floor_weight, out=np.zeros_like(residual_m2),
                              where=floor_weight > 0))
    common_m = bias_quad_per_m * rms_m**2
    return noise_gain * np.asarray(averaged_noise_m2, float) + floor_weight * (floor_m**2
                                                                              + common_m**2)


# A receiver's stated accuracy is the radius holding 68 % of its fixes; for an isotropic 2-D
# Gaussian that radius is sqrt(-2 ln 0.32) = 1.51 sigmas per axis.
RADIUS_68_IN_SIGMAS = float(np.sqrt(-2.0 * np.log(1.0 - 0.68)))


def georef_floor_m(floor_m: float, stated_accuracy_m: float | None) -> float:
    """The per-axis GPS error no window alignment averages out: the configured floor, or the
    receiver's stated accuracy when it says more. A receiver smooths its fixes, so a standalone
    one's error of metres, common to a whole stretch, hides from their scatter and from every
    alignment residual (a real 1 Hz drive: residuals 0.08-0.16 m); only its own statement shows it."""
    if stated_accuracy_m is None:
        return floor_m
    return max(floor_m, stated_accuracy_m / RADIUS_68_IN_SIGMAS)


def horizontal_radius_m(cov_enu: np.ndarray, p: float = 0.95) -> float:
    """Radius of the circle round the estimate that holds the true position with probability ``p``,
    for the horizontal (east, north) part of ``cov_enu`` (exact for a Gaussian, elongated or not)."""
    lam2, lam1 = np.clip(np.linalg.eigvalsh(np.asarray(cov_enu, float)[:2, :2]), 1e-12, None)
    hi = np.sqrt(-2.0 * np.log(1.0 - p) * lam1) + 4.0 * np.sqrt(lam2)  # surely outside
    return float(brentq(lambda r: _inside(r, lam1, lam2) - p, 0.0, hi, xtol=1e-6))


# Gauss-Legendre nodes on [-1, 1]: the integral below is smooth, and a fixed rule evaluated at
# once is ~1000x faster than adaptive quadrature of scalar calls (0.43 s a sign with scipy's
# quad of norm.pdf, most of the triangulate stage).
_NODES, _WEIGHTS = np.polynomial.legendre.leggauss(64)
_Z_MAX = 8.0  # a standard normal holds 1e-15 beyond 8 sigmas


def _inside(r: float, lam1: float, lam2: float) -> float:
    """P(lam1 z1^2 + lam2 z2^2 <= r^2), z1, z2 ~ N(0, 1): over z2, the chance that z1 fits."""
    a = r / np.sqrt(lam2)
    if a <= _Z_MAX:  # z2 = a sin(t): the square root's kink at z2 = +-a becomes smooth
        t = 0.5 * np.pi * _NODES
        z = a * np.sin(t)
        f = (np.exp(-0.5 * z * z) * erf(r * np.cos(t) / np.sqrt(2.0 * lam1)) * a * np.cos(t))
        return float(0.5 * np.pi * (_WEIGHTS @ f) / np.sqrt(2.0 * np.pi))
    z = _Z_MAX * _NODES
    f = np.exp(-0.5 * z * z) * erf(np.sqrt((r * r - lam2 * z * z) / (2.0 * lam1)))
    return float(_Z_MAX * (_WEIGHTS @ f) / np.sqrt(2.0 * np.pi))
