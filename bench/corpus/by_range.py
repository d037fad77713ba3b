"""Relative error against range: each placed sign's per-observation error in the camera's frame
(``metrics.sign_errors``' ``obs_range_err_m``) binned by the true distance from the camera. Small
errors in the rotations and the focal length grow with range; a flat table says they do not."""

from __future__ import annotations

from typing import Callable

import numpy as np

from bench.paper.tables import fmt, md_table

HALVES = ("tuning", "check")
RANGE_EDGES_M = (0.0, 5.0, 10.0, 20.0, 30.0, 40.0, float("inf"))
# The bar's span (a flat table within 0.1 m from 5 m to 40 m).
FLAT_FROM_M, FLAT_TO_M = 5.0, 40.0


def observations(records: list[dict]) -> np.ndarray:
    """(K, 2) [true range m, camera-frame error m] of every placed sign's observations in
    ``records``, in record order."""
    rows = [pair for r in records for e in (r.get("sign_errors") or {}).values()
            for pair in e.get("obs_range_err_m", [])]
    return np.asarray(rows, float).reshape(-1, 2)


def range_bins(obs: np.ndarray) -> list[dict]:
    """Per bin of RANGE_EDGES_M: its bounds, observations, mean, median and p90 error (m; None
    for an empty bin)."""
    out = []
    for lo, hi in zip(RANGE_EDGES_M[:-1], RANGE_EDGES_M[1:]):
        err = obs[(obs[:, 0] >= lo) & (obs[:, 0] < hi), 1]
        stats = ({"mean_m": float(err.mean()), "median_m": float(np.median(err)),
                  "p90_m": float(np.quantile(err, 0.9))} if len(err)
                 else {"mean_m": None, "median_m": None, "p90_m": None})
        out.append({"lo_m": lo, "hi_m": hi, "n": int(len(err)), **stats})
    return out


def spread_m(bins: list[dict]) -> float | None:
    """Largest minus smallest bin mean over the bins within [FLAT_FROM_M, FLAT_TO_M]."""
    means = [b["mean_m"] for b in bins if b["lo_m"] >= FLAT_FROM_M and b["hi_m"] <= FLAT_TO_M
             and b["mean_m"] is not None]
    return max(means) - min(means) if len(means) >= 2 else None


def range_summary(records: list[dict], gps_kind: Callable[[dict], str]) -> dict:
    """Per half, of the journeys with OXTS-like GPS (``gps_kind`` of a record "oxts") and of all:
    the bins and their spread."""
    out: dict = {}
    for half in HALVES:
        mine = [r for r in records if r.get("half") == half]
        for kind in ("oxts", "all"):
            bins = range_bins(observations([r for r in mine
                                            if kind == "all" or gps_kind(r) == kind]))
            out.setdefault(half, {})[kind] = {"bins": bins, "spread_m": spread_m(bins)}
    return out


def _label(b: dict) -> str:
    return f"{b['lo_m']:g}+ m" if b["hi_m"] == float("inf") else f"{b['lo_m']:g}-{b['hi_m']:g} m"


def table_range(summary: dict) -> str:
    """Markdown: relative error per range bin, OXTS-like GPS, both halves."""
    if not any(b["n"] for h in HALVES for b in summary[h]["oxts"]["bins"]):
        return ("### Relative error against range\n\nNo observation with its range (records "
                "written before `obs_range_err_m`, or no sign placed with OXTS-like GPS).")
    rows = []
    for i, b in enumerate(summary[HALVES[0]]["oxts"]["bins"]):
        cells = []
        for h in HALVES:
            x = summary[h]["oxts"]["bins"][i]
            cells.append(f"{x['n']}" if not x["n"] else
                         f"{x['n']}: {fmt(x['mean_m'], 3)} / {fmt(x['median_m'], 3)} / "
                         f"{fmt(x['p90_m'], 3)}")
        rows.append([_label(b), *cells])
    rows.append([f"spread of the means, {FLAT_FROM_M:g}-{FLAT_TO_M:g} m (bar 0.1)",
                 *(fmt(summary[h]["oxts"]["spread_m"], 3) for h in HALVES)])
    return ("### Relative error against range\n\nEach placed sign's error in the camera's frame "
            "per observation, by the true distance from the camera; journeys with OXTS-like GPS. "
            "Observations: mean / median / p90 (m).\n\n"
            + md_table(["range", *HALVES], rows))
