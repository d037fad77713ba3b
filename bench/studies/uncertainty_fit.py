"""Choose the sign-uncertainty knobs on a corpus run's tuning half and check them on its check half.

A full ``signmap bench corpus`` run records, per placed sign, its horizontal error against the
truth and the terms of its covariance before the knobs weigh them (``bench.paper.metrics``):
the triangulation's (2, 2) block, the averaged GPS noise, the floor weight and the alignment
residual (``app.pipeline.geometry.uncertainty.GeorefTerms``). That is enough to recompute every
sign's 95 % radius for any knob values without running the pipeline again.

``fit`` picks ``sign_georef_floor_m`` and ``sign_georef_bias_quad_per_m`` (the gain on the
averaged noise stays 1: that term is the alignment's own statistics) so that, on the tuning half,
the share of all signs inside their radius is nearest 95 %, for each GPS kind and overall. A floor
alone cannot do it, as OXTS-like and phone-like GPS errors differ tenfold; the square term follows
the receiver, whose common error grows faster than its residual. The report gives each GPS kind
apart.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

from app.pipeline.geometry.uncertainty import (GeorefTerms, georef_horizontal_m2,
                                               horizontal_radius_m)
from bench.corpus.report import GPS_KINDS, gps_kind

TARGET = 0.95


@dataclass(frozen=True)
class Knobs:
    floor_m: float
    noise_gain: float = 1.0
    bias_quad_per_m: float = 0.0


@dataclass(frozen=True)
class SignTerms:
    """One placed sign of a corpus run: its horizontal error and its covariance terms."""

    half: str
    gps: str
    h_err_m: float
    cov_tri_h_m2: np.ndarray  # (2, 2)
    georef: GeorefTerms

    def r95_m(self, knobs: Knobs) -> float:
        h = self.georef.horizontal_m2(knobs.floor_m, knobs.noise_gain,
                                      bias_quad_per_m=knobs.bias_quad_per_m)
        return horizontal_radius_m(self.cov_tri_h_m2 + h * np.eye(2))


def sign_terms(records: list[dict]) -> list[SignTerms]:
    """Every sign of ``records`` (corpus JSONL journey records) that carries its terms."""
    out = []
    for r in records:
        for e in (r.get("sign_errors") or {}).values():
            if "georef_noise_m2" not in e or e.get("h_err_m") is None:
                continue
            out.append(SignTerms(r.get("half", ""), gps_kind(r), float(e["h_err_m"]),
                                 np.asarray(e["cov_tri_h_m2"], float),
                                 GeorefTerms(e["georef_noise_m2"], e["georef_floor_weight"],
                                             e.get("georef_residual_m2", 0.0))))
    return out


# Standard normal pairs shared by every call: whether a sign's error lies inside its 95 % radius
# is whether the Gaussian puts at most 95 % of its mass within that error, a Monte Carlo mean
# vectorised over signs (the exact radius, ``r95_m``, costs an integral per sign and knob value).
_Z2 = np.random.default_rng(0).standard_normal((4000, 2)) ** 2


class _Signs:
    """The terms of a list of signs as arrays, read once: a fit evaluates thousands of knob values
    on the same signs. The Gaussian's mass within a sign's error only falls as the added variance
    ``h`` grows, so each sign is inside its radius exactly when ``h`` reaches a threshold of its
    own, found once by bisection; a knob value then costs a comparison per sign."""

    def __init__(self, signs: list[SignTerms]):
        # Adding h * I to the triangulation block adds h to both of its eigenvalues.
        self.lam_tri = np.array([np.clip(np.linalg.eigvalsh(s.cov_tri_h_m2), 0.0, None)
                                 for s in signs]).reshape(-1, 2)                     # (S, 2)
        self.noise = np.array([s.georef.averaged_noise_m2 for s in signs])         # (S,)
        self.floor_w = np.array([s.georef.floor_weight for s in signs])            # (S,)
        self.residual = np.array([s.georef.residual_m2 for s in signs])            # (S,)
        self.err2 = np.array([s.h_err_m**2 for s in signs])                        # (S,)
        self.h_inside = self._threshold_m2()                                       # (S,)

    def _inside_at(self, h: np.ndarray) -> np.ndarray:
        lam = np.clip(self.lam_tri + h[:, None], 1e-12, None)
        mass_within_err = np.mean(_Z2 @ lam.T <= self.err2[None, :], axis=0)
        return mass_within_err <= TARGET

    def _threshold_m2(self) -> np.ndarray:
        """(S,) the smallest added variance that puts each sign inside its radius. At
        ``h = err^2 / 0.1`` every sign is inside (z1^2 + z2^2 <= 0.1 has 5 % of the mass)."""
        lo = np.zeros_like(self.err2)
        hi = self.err2 / 0.1 + 1e-12
        inside_at_zero = self._inside_at(lo)
        for _ in range(60):
            mid = 0.5 * (lo + hi)
            ok = self._inside_at(mid)
            hi, lo = np.where(ok, mid, hi), np.where(ok, lo, mid)
        return np.where(inside_at_zero, 0.0, hi)

    def inside(self, knobs: Knobs) -> np.ndarray:
        """(S,) bool: each sign's true position is inside its 95 % radius (the variance as
        ``georef_horizontal_m2`` adds it, as the pipeline does)."""
        h = georef_horizontal_m2(self.noise, self.floor_w, self.residual, knobs.floor_m,
                                 knobs.noise_gain,
                                 bias_quad_per_m=knobs.bias_quad_per_m)
        return h >= self.h_inside


def coverage(signs: list[SignTerms], knobs: Knobs) -> tuple[float | None, int]:
    """(share of ``signs`` whose true position is inside their 95 % radius, how many signs)."""
    if not signs:
        return None, 0
    return float(np.mean(_Signs(signs).inside(knobs))), len(signs)


def fit(signs: list[SignTerms], floors_m=np.arange(0.0, 0.61, 0.05),
        quads_per_m=np.arange(0.0, 0.61, 0.05)) -> Knobs:
    """The knobs that bring the coverage of each GPS kind and of all ``signs`` nearest to 95 %
    (the sum of squared misses); among equals, the smallest radii (a grid: the coverage is a step
    function of the knobs). Overall first and kinds second let an exact 95 % overall made of
    100 % and 90 % beat an honest 94.7 % and 95.2 %."""
    arrays = _Signs(signs)
    kinds = np.array([s.gps for s in signs])
    groups = [m for kind in GPS_KINDS if (m := kinds == kind).any()]

    def cost(k: Knobs) -> tuple[float, float]:
        inside = arrays.inside(k)
        per_kind = sum((float(np.mean(inside[m])) - TARGET) ** 2 for m in groups)
        overall = (float(np.mean(inside)) - TARGET) ** 2
        return (round(per_kind + overall, 5), k.floor_m + k.bias_quad_per_m)
    candidates = [Knobs(float(f), 1.0, float(q))
                  for f, q in itertools.product(floors_m, quads_per_m)]
    return min(candidates, key=cost)


def describe(k: Knobs) -> str:
    return f"floor {k.floor_m:.2f} m, square {k.bias_quad_per_m:.2f} /m"


def report(records: list[dict], current: Knobs) -> tuple[Knobs, str]:
    """(knobs fitted on the tuning half, a markdown table of coverage per half and GPS kind with
    the current and the fitted knobs)."""
    signs = sign_terms(records)
    fitted = fit([s for s in signs if s.half == "tuning"])
    rows = []
    for half in ("tuning", "check"):
        for kind in (*GPS_KINDS, "all"):
            chosen = [s for s in signs if s.half == half and kind in ("all", s.gps)]
            cells = []
            for knobs in (current, fitted):
                share, n = coverage(chosen, knobs)
                cells.append("–" if share is None else f"{100 * share:.1f} % of {n}")
            rows.append(f"| {half} | {kind} | {cells[0]} | {cells[1]} |")
    head = (f"| half | GPS | inside r95, current ({describe(current)}) | inside r95, fitted "
            f"({describe(fitted)}) |\n| --- | --- | --- | --- |")
    return fitted, "\n".join([head, *rows])
