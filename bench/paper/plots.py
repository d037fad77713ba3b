"""PNG figures of a bench run (matplotlib, Agg): a journey's trajectories and signs from above, the
sensitivity study (like the paper's Fig. 3) and the map error against the number of journeys."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402  (after the backend is chosen)
import numpy as np  # noqa: E402

from app.pipeline.types import JourneyResult  # noqa: E402
from bench.paper.metrics import result_to_truth_enu, truth_centres_enu, truth_frame  # noqa: E402

# Drawn in this order, ours last (on top); different sign markers keep coinciding runs visible.
STYLE = {"naive": ("tab:purple", "D", 6, "naive COLMAP"),
         "gt": ("tab:green", "s", 6, "ground-truth camera"),
         "ours": ("tab:red", "o", 10, "ours (self-calibrated)")}


def _sign_xyz(result: JourneyResult, truth: dict) -> np.ndarray:
    if not result.signs:
        return np.zeros((0, 3))
    alt = [s.alt_m if s.alt_m is not None else np.nan for s in result.signs]
    return truth_frame(truth).to_local([s.lat_deg for s in result.signs],
                                       [s.lon_deg for s in result.signs], alt)


def plot_journey(name: str, truth: dict, results: dict[str, JourneyResult | None],
                 png: Path) -> Path:
    """Top view (east, north) in truth ENU: true path, GPS fixes, estimated camera centres and
    signs of the ``ours`` / ``gt`` / ``naive`` runs, true signs."""
    fig, ax = plt.subplots(figsize=(9, 8))
    xyz_true = np.array(list(truth_centres_enu(truth).values()))
    ax.plot(xyz_true[:, 0], xyz_true[:, 1], "k-", lw=1.0, label="true path")
    gps_done = False
    for variant, (color, marker, size, label) in STYLE.items():
        result = results.get(variant)
        if result is None or len(result.trajectory_enu) == 0:
            continue
        if not gps_done:
            gps = result_to_truth_enu(result, result.gps_enu, truth)
            ax.plot(gps[:, 0], gps[:, 1], ".", color="0.6", ms=3, label="GPS (posed frames)")
            gps_done = True
        traj = result_to_truth_enu(result, result.trajectory_enu, truth)
        ax.plot(traj[:, 0], traj[:, 1], ".", color=color, ms=2, label=f"{label}: cameras")
        signs = _sign_xyz(result, truth)
        ax.plot(signs[:, 0], signs[:, 1], marker, mfc="none", mec=color, ms=size, ls="none",
                label=f"{label}: {len(signs)} signs")
    true_signs = np.array([s["xyz_enu"] for s in truth["signs"]]).reshape(-1, 3)
    ax.plot(true_signs[:, 0], true_signs[:, 1], "k^", ms=5, label="true signs")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("east (m)")
    ax.set_ylabel("north (m)")
    ax.set_title(f"{name}: trajectories and signs (truth ENU)")
    ax.grid(True, lw=0.3)
    ax.legend(fontsize=7, loc="best")
    return save_figure(fig, png)


def plot_sensitivity(rows: list[dict], groups: list[str], png: Path) -> Path:
    """One panel per parameter group: mean relative and absolute sign error vs % camera error.
    ``rows``: dicts with ``group``, ``error_pct``, ``rel_mean_m``, ``abs_mean_m``."""
    fig, axes = plt.subplots(len(groups), 1, figsize=(6, 2.6 * len(groups)), squeeze=False)
    for ax, group in zip(axes[:, 0], groups):
        pts = sorted((r for r in rows if r["group"] == group), key=lambda r: r["error_pct"])
        x = [r["error_pct"] for r in pts]
        ax.plot(x, [_nan(r["rel_mean_m"]) for r in pts], "o-", color="tab:blue",
                label="relative")
        ax.set_ylabel("rel. error (m)", color="tab:blue")
        twin = ax.twinx()
        twin.plot(x, [_nan(r["abs_mean_m"]) for r in pts], "s--", color="tab:orange",
                  label="absolute")
        twin.set_ylabel("abs. error (m)", color="tab:orange")
        ax.set_title(f"error in {group}", fontsize=10)
        ax.grid(True, lw=0.3)
    axes[-1, 0].set_xlabel("parameter error (%)")
    return save_figure(fig, png)


def plot_fusion(rows: list[dict], bar_m: float, bar_k: int, png: Path) -> Path:
    """Median and mean absolute error of the fused map vs the number of journeys, the bar (a line
    at ``bar_m``, marked at ``bar_k`` journeys) and the single-journey mean. ``rows``: dicts with
    ``k``, ``abs_median_m``, ``abs_mean_m``, ``single_abs_mean_m``."""
    fig, ax = plt.subplots(figsize=(6.5, 4.2))
    k = [r["k"] for r in rows]
    ax.plot(k, [_nan(r["abs_median_m"]) for r in rows], "o-", color="tab:red",
            label="fused map: median")
    ax.plot(k, [_nan(r["abs_mean_m"]) for r in rows], "s--", color="tab:orange",
            label="fused map: mean")
    ax.plot(k, [_nan(r["single_abs_mean_m"]) for r in rows], "^:", color="tab:blue",
            label="single journey: mean (same journeys)")
    ax.axhline(bar_m, color="k", lw=1.0, ls="-.", label=f"bar: median {bar_m} m")
    if bar_k <= max(k, default=0):  # a quick run stops short of the bar's journey count
        ax.axvline(bar_k, color="0.6", lw=0.8, ls=":")
    ax.set_xticks(k)
    ax.set_xlabel("journeys fused")
    ax.set_ylabel("absolute sign error (m, ENU 3-D)")
    ax.set_ylim(bottom=0.0)
    ax.set_title("Map error vs number of journeys")
    ax.grid(True, lw=0.3)
    ax.legend(fontsize=8, loc="best")
    return save_figure(fig, png)


def save_figure(fig, png: Path) -> Path:
    fig.tight_layout()
    png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(png, dpi=110)
    plt.close(fig)
    return png


def _nan(value) -> float:
    return float("nan") if value is None else float(value)
