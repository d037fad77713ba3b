"""The corpus bench's report: statistics of the journey records ``bench.corpus.run`` writes, as
markdown tables (tuning and check halves side by side), JSON and one PNG.

A calibration is *accepted* when the run self-calibrated; it *failed* when the run ended without
a calibration (at the calibration stage, or before it); *later* when the run failed after the
calibration stage (ego-motion, alignment), whose calibration is then unknown: such journeys are
left out of the success rates (``--calibrate-only`` has none).
"""

from __future__ import annotations

import json
import math
import re
from collections import Counter
from pathlib import Path
from typing import Callable, Iterable

import numpy as np
from scipy.stats import bootstrap

from bench.corpus.antenna import antenna_summary, table_antenna
from bench.corpus.broken import broken_summary, table_broken
from bench.corpus.by_range import range_summary, table_range
from bench.paper.metrics import true_distortion_error_px
from bench.paper.plots import save_figure, plt
from bench.paper.runner import finite
from bench.paper.tables import fmt, md_table

HALVES = ("tuning", "check")
# The acceptance bar of a calibration, and what counts as accepted but wrong.
BAR = {"fx_pct": 1.0, "fy_pct": 1.0, "cx_px": 4.0, "cy_px": 4.0, "k1_pct": 5.0}
WRONG_FOCAL_PCT = 3.0
# Not the bar: 5 % of a near-zero k1 (-0.02, say) is 0.001, a tenth of a pixel at the corners of
# most of the corpus's lenses; beside the bar the report also counts k1 within this absolute
# error, so a reader sees which bar misses are of that kind.
K1_ABS_FLOOR = 0.005
BAR_TEXT = "Bar: |fx|, |fy| ≤ 1 %, |cx|, |cy| ≤ 4 px, |k1| ≤ 5 %."  # BAR, for a report's head
STEEP_TURN_DEG, GENTLE_TURN_DEG = 45.0, 30.0
# distortion_px: metrics.true_distortion_error_px, reported beside the bar (not part of it).
ERROR_KEYS = ("fx_pct", "fy_pct", "cx_px", "cy_px", "k1_pct", "k2_pct", "distortion_px")
LATER_STAGES = {"ego_motion", "align", "triangulate"}
MAX_CATEGORIES = 12  # a string parameter with more values is an id, not a category


def param(r: dict, key: str):
    """A journey parameter; the field of view from width and fx when the corpus omits it."""
    p = r["params"]
    if key == "hfov_deg" and p.get(key) is None and p.get("width") and p.get("fx"):
        return math.degrees(2 * math.atan(p["width"] / (2 * p["fx"])))
    return p.get(key)


def outcome(r: dict) -> str:
    """"accepted", "failed", "later" (failed after calibrating) or "other" (finished with a
    calibration it did not make itself)."""
    if r["status"] == "ok":
        return "accepted" if (r.get("calibration") or {}).get("source") == "self" else "other"
    stage = (r.get("error") or "").partition(":")[0]
    return "later" if stage in LATER_STAGES else "failed"


def error(r: dict, key: str) -> float | None:
    cal = r.get("calibration") or {}
    value = (cal.get("errors") or {}).get(key)
    if value is None and key == "distortion_px" and cal.get("camera"):
        # Records written before the field: the truth is in the journey's parameters.
        value = true_distortion_error_px(cal["camera"], r["params"])
    return value


def is_wrong(r: dict) -> bool:
    """An accepted calibration off by more than WRONG_FOCAL_PCT in fx or fy: the worst outcome,
    as the service would use it without complaint."""
    return outcome(r) == "accepted" and any(
        abs(error(r, k) or 0.0) > WRONG_FOCAL_PCT for k in ("fx_pct", "fy_pct"))


def meets_bar(r: dict, keys: Iterable[str] = tuple(BAR)) -> bool:
    return all(error(r, k) is not None and abs(error(r, k)) <= BAR[k] for k in keys)


def meets_bar_k1_floor(r: dict) -> bool:
    """The bar, with k1 also passing when within K1_ABS_FLOOR of the truth."""
    k1_abs = error(r, "k1_abs")
    k1_ok = meets_bar(r, ("k1_pct",)) or (k1_abs is not None and abs(k1_abs) <= K1_ABS_FLOOR)
    return k1_ok and meets_bar(r, ("fx_pct", "fy_pct", "cx_px", "cy_px"))


def stage2_std(r: dict, n: int) -> list[float] | None:
    """The first ``n`` of stage 2's standard deviations (``intrinsics_std``: fx, fy, cx, cy, k1,
    k2) of an accepted record, when it has them all finite; else None."""
    std = (r.get("calibration") or {}).get("intrinsics_std") or []
    if outcome(r) != "accepted" or len(std) < n or not all(map(math.isfinite, std[:n])):
        return None
    return std[:n]


def sigma_ratios(records: list[dict]) -> dict[str, list[float]]:
    """|error| / stage 2's own sigma for fx, cx and cy of each accepted record that has it: how
    far its covariance understates the real error (1: honest)."""
    out: dict[str, list[float]] = {"fx": [], "cx": [], "cy": []}
    for r in records:
        if (std := stage2_std(r, 4)) is None:
            continue
        cal = r["calibration"]
        fx_pct = error(r, "fx_pct")
        if fx_pct is not None and std[0] > 0:
            out["fx"].append(abs(fx_pct) / (100 * std[0] / cal["camera"]["fx"]))
        for k, i in (("cx", 2), ("cy", 3)):
            if (e := error(r, f"{k}_px")) is not None and std[i] > 0:
                out[k].append(abs(e) / std[i])
    return out


# Where the misses sit against stage 2's own sigma (its covariance): bins of the larger of fx's
# and fy's sigma (% of the value), and of k1's bar (5 % of the true |k1|) in sigmas of k1. A bar
# under one sigma is one the data do not resolve, whatever the method; and the real error is a
# median 1.4-1.9 times the sigma on the corpus's halves (``sigma_ratios``).
FOCAL_SIGMA_EDGES_PCT = (0.1, 0.2, 0.3)
K1_BAR_EDGES_SIGMAS = (1.0, 4.0)


def own_sigmas(r: dict) -> tuple[float, float] | None:
    """(larger of fx's and fy's sigma in %, k1's bar in sigmas of k1) of an accepted record with
    stage 2's covariance (``intrinsics_std``), else None."""
    std, k1 = stage2_std(r, 5), r["params"].get("k1")
    cam = (r.get("calibration") or {}).get("camera")
    if std is None or not cam or k1 is None or min(std) <= 0:
        return None
    focal_pct = max(100 * std[0] / cam["fx"], 100 * std[1] / cam["fy"])
    return focal_pct, BAR["k1_pct"] / 100 * abs(k1) / std[4]


def _bin_labels(edges: tuple[float, ...], unit: str) -> list[str]:
    return ([f"< {edges[0]:g}{unit}"]
            + [f"{a:g}-{b:g}{unit}" for a, b in zip(edges, edges[1:])] + [f"≥ {edges[-1]:g}{unit}"])


def misses_by_sigma(records: list[dict]) -> list[tuple[str, int, int]]:
    """(bin label, accepted records in it, of them outside the bar's fx/fy or k1 part) per bin of
    ``own_sigmas``: first the focal bins (misses: fx or fy), then the k1 bins (misses: k1)."""
    rows = [(r, s) for r in records if (s := own_sigmas(r)) is not None]
    out = []
    for i, (edges, label, unit, keys) in enumerate((
            (FOCAL_SIGMA_EDGES_PCT, "fx, fy sigma (the larger)", " %", ("fx_pct", "fy_pct")),
            (K1_BAR_EDGES_SIGMAS, "k1 bar (5 % of \\|k1\\|) in sigmas of k1", "", ("k1_pct",)))):
        where = np.digitize([s[i] for _, s in rows], edges)
        for b, name in enumerate(_bin_labels(edges, unit)):
            inside = [r for (r, _), w in zip(rows, where) if w == b]
            missed = sum(not meets_bar(r, keys) for r in inside)
            out.append((f"{label} {name}", len(inside), missed))
    return out


def is_steep(r: dict) -> bool:
    return (r["params"].get("max_turn_deg") or 0.0) >= STEEP_TURN_DEG


def is_gentle(r: dict) -> bool:
    turn = r["params"].get("max_turn_deg")
    return r["params"].get("kind") == "gentle" or (turn is not None and turn < GENTLE_TURN_DEG)


def quantile(values: Iterable[float | None], q: float) -> float | None:
    vals = [v for v in values if v is not None and math.isfinite(v)]
    return float(np.percentile(vals, q)) if vals else None


def success_rate(records: list[dict], where: Callable[[dict], bool] = lambda r: True) -> dict:
    decided = [outcome(r) for r in records if where(r) and outcome(r) != "later"]
    return {"accepted": decided.count("accepted"), "n": len(decided)}


def half_summary(records: list[dict]) -> dict:
    """Counts, success rates, error quantiles, bar shares and times of one half's records."""
    accepted = [r for r in records if outcome(r) == "accepted"]
    errors = {k: [abs(e) for r in accepted if (e := error(r, k)) is not None] for k in ERROR_KEYS}
    outcomes = [outcome(r) for r in records]
    signed = [r for r in records if r.get("signs")]
    return {
        "n": len(records), **{o: outcomes.count(o) for o in ("accepted", "failed", "later")},
        "rate_all": success_rate(records), "rate_steep": success_rate(records, is_steep),
        "rate_gentle": success_rate(records, is_gentle),
        "median": {k: quantile(v, 50) for k, v in errors.items()},
        "p90": {k: quantile(v, 90) for k, v in errors.items()},
        "within": {"fx, fy ≤ 1 %": sum(meets_bar(r, ("fx_pct", "fy_pct")) for r in accepted),
                   "cx, cy ≤ 4 px": sum(meets_bar(r, ("cx_px", "cy_px")) for r in accepted),
                   "k1 ≤ 5 %": sum(meets_bar(r, ("k1_pct",)) for r in accepted),
                   "all (the bar)": sum(meets_bar(r) for r in accepted),
                   f"all, k1 also within ±{K1_ABS_FLOOR:g} (not the bar)":
                       sum(meets_bar_k1_floor(r) for r in accepted)},
        "sigma_ratio": {k: (quantile(v, 50), quantile(v, 90))
                        for k, v in sigma_ratios(records).items()},
        "wrong": sorted(r["name"] for r in accepted if is_wrong(r)),
        "by_sigma": misses_by_sigma(records),
        "calib_s_median": quantile((r.get("calib_s") for r in records), 50),
        "calib_s_p90": quantile((r.get("calib_s") for r in records), 90),
        "wall_s_median": quantile((r.get("wall_s") for r in records), 50),
        # Full runs only (not --calibrate-only): the sign metrics of the suite, per journey.
        "signs_placed": sum(r["signs"]["n_signs"] + r["signs"].get("n_false", 0)
                            + r["signs"].get("n_duplicate", 0) for r in signed),
        "signs_mappable": sum(r["signs"]["n_mappable"] for r in signed),
        "signs_mappable_found": sum(r["signs"].get("n_mappable_found", 0) for r in signed),
        "signs_false": sum(r["signs"].get("n_false", 0) for r in signed),
        "signs_duplicate": sum(r["signs"].get("n_duplicate", 0) for r in signed),
        "abs_median_m": quantile((r["signs"]["abs_median_m"] for r in signed), 50),
        "facing_median_deg": quantile((r["signs"].get("facing_median_deg") for r in signed), 50),
        **sign_error_stats(signed),
        "by_gps": {kind: sign_error_stats([r for r in signed if gps_kind(r) == kind])
                   for kind in GPS_KINDS}}


GPS_KINDS = ("oxts", "phone")


def gps_kind(record: dict) -> str:
    """"oxts" for OXTS-like GPS (white noise <= 0.3 m, bias sigma <= 0.15 m), else "phone"."""
    p = record.get("params", {})
    oxts = p.get("gps_white_sigma_m", 9.9) <= 0.3 and p.get("gps_bias_sigma_m", 9.9) <= 0.15
    return "oxts" if oxts else "phone"


def sign_error_stats(signed: list[dict]) -> dict:
    """Over every placed sign of ``signed`` records: the absolute error's median and 90th
    percentile, the share inside its own 95 % horizontal radius, and the median over journeys of
    the slope of absolute error against distance along the journey (m per 100 m), and that slope
    pooled within journeys with its standard error (``pooled_slope``)."""
    per_journey = [list((r.get("sign_errors") or {}).values()) for r in signed]
    errs = [e for js in per_journey for e in js]
    rel_by_journey = [[e["rel_m"] for e in js if e.get("rel_m") is not None
                       and np.isfinite(e["rel_m"])] for js in per_journey]
    covered_by_journey = [[float(e["within_r95"]) for e in js if e.get("within_r95") is not None]
                          for js in per_journey]
    rel = [v for js in rel_by_journey for v in js]
    covered = [v for js in covered_by_journey for v in js]
    slopes, spanning = [], []  # spanning: each such journey's (s_m, abs_m) points
    for r in signed:
        pts = np.array([(e["s_m"], e["abs_m"]) for e in (r.get("sign_errors") or {}).values()
                        if e.get("s_m") is not None and e.get("abs_m") is not None], float)
        if len(pts) >= 3 and np.ptp(pts[:, 0]) > 50.0:
            slopes.append(100.0 * np.polyfit(pts[:, 0], pts[:, 1], 1)[0])
            spanning.append(pts)
    pooled, pooled_se = pooled_slope(spanning)
    gps = [r["params"]["gps_white_sigma_m"] for r in signed
           if r.get("params", {}).get("gps_white_sigma_m") is not None]
    return {"n_sign_errors": len(errs), "n_journeys": len(signed),
            "rel_mean_m": float(np.mean(rel)) if rel else None,
            "gps_white_median_m": quantile(gps, 50),
            "sign_abs_median_m": quantile((e.get("abs_m") for e in errs), 50),
            "sign_abs_p90_m": quantile((e.get("abs_m") for e in errs), 90),
            "rel_mean_ci90_m": journey_interval(rel_by_journey),
            "r95_coverage": (sum(covered) / len(covered)) if covered else None,
            "r95_coverage_ci90": journey_interval(covered_by_journey),
            "n_covered_of": len(covered),
            "slope_m_per_100m": quantile(slopes, 50),
            "slope_pooled_m_per_100m": pooled, "slope_pooled_se_m_per_100m": pooled_se}


def journey_interval(values_by_journey: list[list[float]], level: float = 0.9
                     ) -> list[float] | None:
    """The ``level`` percentile interval of the mean of all values, resampling journeys (not
    values): a journey's signs share its GPS error and its reconstruction, so with ten journeys a
    half one journey moves a share by ten points, which a per-sign interval would hide. None with
    fewer than two journeys that have values."""
    groups = [np.asarray(v, float) for v in values_by_journey if len(v)]
    if len(groups) < 2:
        return None

    def pooled_mean(idx: np.ndarray) -> float:
        return float(np.mean(np.concatenate([groups[i] for i in idx.astype(int)])))

    res = bootstrap((np.arange(len(groups)),), pooled_mean, vectorized=False, n_resamples=2000,
                    confidence_level=level, method="percentile", random_state=0)
    return [float(res.confidence_interval.low), float(res.confidence_interval.high)]


def pooled_slope(journeys: list[np.ndarray]) -> tuple[float | None, float | None]:
    """(slope, its standard error), m per 100 m, of absolute error against distance along the
    journey, fitted to every journey's signs at once with each journey's own mean removed
    (``journeys``: per journey (K, 2) of (s_m, abs_m)). One journey's 5-25 signs over 80-300 m
    give a noisy slope of their own, and a median of those hides whether the error grows."""
    xs = [p[:, 0] - p[:, 0].mean() for p in journeys]
    ys = [p[:, 1] - p[:, 1].mean() for p in journeys]
    x, y = (np.concatenate(v) if v else np.zeros(0) for v in (xs, ys))
    dof = len(x) - len(journeys) - 1
    if dof < 1 or not np.any(x):
        return None, None
    slope = float(x @ y / (x @ x))
    residual = y - slope * x
    se = float(np.sqrt(residual @ residual / dof / (x @ x)))
    return 100.0 * slope, 100.0 * se


def normalise(text: str) -> str:
    """A message with its numbers replaced ("only 3/22 frames" -> "only N/M frames", other
    numbers -> X), so that the same cause groups together."""
    text = re.sub(r"\d+/\d+", "N/M", text)
    return re.sub(r"(?<![\w.])\d+(?:\.\d+)?", "X", text)


def failure_reasons(message: str | None) -> list[str]:
    """The distinct normalised reasons of one failure; a self-calibration failure lists one per
    candidate window ("frames a-b: why; ..."), each counted once per journey."""
    if not message:
        return ["(no message)"]
    stage, sep, rest = message.partition(": ")
    if not sep:
        return [normalise(message)]
    _, every, windows = rest.partition("failed on every turn window: ")
    parts = windows.split("; ") if every else [rest]
    return sorted({f"{stage}: " + normalise(re.sub(r"^frames \d+-\d+: ", "", p.strip()))
                   for p in parts})


def group_failures(records: list[dict]) -> list[dict]:
    """Each reason with its count of failed journeys per half and a few names, commonest first."""
    groups: dict[str, dict] = {}
    for r in records:
        if r["status"] == "ok":
            continue
        for reason in failure_reasons(r.get("error")):
            g = groups.setdefault(reason, {"reason": reason, "names": [],
                                           **{h: 0 for h in HALVES}})
            g[r.get("half")] = g.get(r.get("half"), 0) + 1
            g["names"].append(r["name"])
    return sorted(groups.values(), key=lambda g: (-len(g["names"]), g["reason"]))


def _param_kinds(records: list[dict]) -> tuple[list[str], list[str]]:
    """(numeric, categorical) parameter names over all records."""
    values: dict[str, list] = {}
    for r in records:
        for k, v in r["params"].items():
            values.setdefault(k, []).append(v)
    numeric, categorical = [], []
    for k, vs in sorted(values.items()):
        vs = [v for v in vs if v is not None]
        if vs and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in vs):
            numeric.append(k)
        elif vs and all(isinstance(v, (str, bool)) for v in vs) and \
                len(set(vs)) <= MAX_CATEGORIES:
            categorical.append(k)
    return numeric, categorical


def param_comparison(records: list[dict]) -> dict:
    """What the failures share, per half: each numeric parameter's median over the failed and
    the accepted journeys; each categorical value's failure count out of the decided journeys."""
    numeric, categorical = _param_kinds(records)
    out: dict = {"numeric": {}, "categorical": {}}
    for half in HALVES:
        rows = [r for r in records if r.get("half") == half]
        for k in numeric:
            out["numeric"].setdefault(k, {})[half] = {
                o: quantile((r["params"].get(k) for r in rows if outcome(r) == o), 50)
                for o in ("failed", "accepted")}
        for k in categorical:
            for r in rows:
                if k in r["params"] and outcome(r) in ("accepted", "failed", "other"):
                    cell = out["categorical"].setdefault(f"{k} = {r['params'][k]}", {}).setdefault(
                        half, {"failed": 0, "n": 0})
                    cell["failed"] += outcome(r) == "failed"
                    cell["n"] += 1
    return out


CLOCK_CLOSE_S = 0.1  # a clock offset this close is as good as declared (the e2e test's bar)


def clock_summary(records: list[dict]) -> dict | None:
    """How well the camera clock errors of a video run (``run_corpus(as_video=True)``) were
    estimated: |estimated - true| over the journeys estimated; the commonest normalised reason of
    those not. None for a frames run."""
    rows = [r for r in records if "clock_error_s" in r]
    if not rows:
        return None
    # Rounded: the estimate is read off a report to 0.01 s, and 2.9 against 3 must be within 0.1.
    errors = [round(abs(r["clock_error_est_s"] - r["clock_error_s"]), 6) for r in rows
              if r.get("clock_error_est_s") is not None]
    reasons = Counter(normalise(r.get("clock_offset_reason") or "(no reason)") for r in rows
                      if r.get("clock_error_est_s") is None)
    commonest = reasons.most_common(1)
    return {"n": len(rows), "n_estimated": len(errors),
            "abs_error_median_s": quantile(errors, 50), "abs_error_p90_s": quantile(errors, 90),
            "abs_error_max_s": float(max(errors)) if errors else None,
            "n_within_close": sum(e <= CLOCK_CLOSE_S for e in errors),
            "n_not_estimated": len(rows) - len(errors),
            "commonest_reason": commonest[0][0] if commonest else None,
            "commonest_reason_n": commonest[0][1] if commonest else 0}


def build_report(meta: dict, records: list[dict]) -> dict:
    by_half = {h: [r for r in records if r.get("half") == h] for h in HALVES}
    return {"meta": meta, "summary": {h: half_summary(rs) for h, rs in by_half.items()},
            "failures": group_failures(records), "params": param_comparison(records),
            "clock": clock_summary(records), "by_range": range_summary(records, gps_kind),
            "antenna": antenna_summary(records), "broken": broken_summary(records),
            "journeys": records}


def _rate(rate: dict) -> str:
    return f"{rate['accepted']}/{rate['n']} ({100 * rate['accepted'] / rate['n']:.0f} %)" \
        if rate["n"] else "–"


def table_summary(report: dict) -> str:
    return "### Summary\n\n" + md_table(["", *HALVES], summary_rows(report))


def summary_rows(report: dict) -> list[list[str]]:
    """The summary table's rows: [label, tuning cell, check cell]."""
    s = [report["summary"][h] for h in HALVES]
    rows = [["journeys run", *(str(x["n"]) for x in s)],
            ["accepted / failed / failed after calibrating",
             *(f"{x['accepted']} / {x['failed']} / {x['later']}" for x in s)],
            ["calibration success, all", *(_rate(x["rate_all"]) for x in s)],
            [f"… max turn ≥ {STEEP_TURN_DEG:.0f}°", *(_rate(x["rate_steep"]) for x in s)],
            [f"… gentle only (< {GENTLE_TURN_DEG:.0f}° or kind gentle)",
             *(_rate(x["rate_gentle"]) for x in s)]]
    for k in ERROR_KEYS:
        name, unit = k.split("_")
        rows.append([f"\\|{name}\\| {'%' if unit == 'pct' else 'px'} median / p90",
                     *(f"{fmt(x['median'][k], 2)} / {fmt(x['p90'][k], 2)}" for x in s)])
    for label in s[0]["within"]:
        rows.append([f"accepted with {label}",
                     *(f"{x['within'][label]}/{x['accepted']}" for x in s)])
    rows.append(["\\|error\\| / stage 2's own sigma, fx, cx, cy: median / p90",
                 *(", ".join(f"{fmt(a, 1)} / {fmt(b, 1)}" for a, b in x["sigma_ratio"].values())
                   for x in s)])
    rows += [[f"accepted but > {WRONG_FOCAL_PCT:.0f} % off in fx or fy",
              *(f"**{len(x['wrong'])}**" + (f": {', '.join(x['wrong'])}" if x["wrong"] else "")
                for x in s)],
             ["calibrate stage s median / p90",
              *(f"{fmt(x['calib_s_median'], 1)} / {fmt(x['calib_s_p90'], 1)}" for x in s)],
             ["total wall s median", *(fmt(x["wall_s_median"], 1) for x in s)]]
    if any(x["signs_mappable"] for x in s):
        rows += [["signs placed (all journeys)", *(str(x["signs_placed"]) for x in s)],
                 ["recall: mappable signs placed (≥ 5 frames, ≥ 12 px)",
                  *(f"{x['signs_mappable_found']}/{x['signs_mappable']}"
                    + (f" ({100 * x['signs_mappable_found'] / x['signs_mappable']:.0f} %)"
                       if x["signs_mappable"] else "") for x in s)],
                 ["false signs / duplicates (> 3 m from any true sign / a second for one)",
                  *(f"{x['signs_false']} / {x['signs_duplicate']}" for x in s)],
                 ["relative (per-frame camera) error mean (m) [90 % interval over journeys]",
                  *(fmt(x.get("rel_mean_m"), 3) + _interval(x.get("rel_mean_ci90_m"), 1.0, 3)
                    for x in s)],
                 ["median of journeys' abs median sign error (m)",
                  *(fmt(x["abs_median_m"], 3) for x in s)],
                 ["median of journeys' median facing error (deg)",
                  *(fmt(x.get("facing_median_deg"), 1) for x in s)],
                 ["all signs: abs error median / p90 (m)",
                  *(f"{fmt(x.get('sign_abs_median_m'), 3)} / {fmt(x.get('sign_abs_p90_m'), 3)}"
                    for x in s)],
                 ["true position inside the 95 % horizontal radius [90 % interval over journeys]",
                  *(f"{fmt(100 * x['r95_coverage'], 1)} % of {x['n_covered_of']}"
                    + _interval(x.get("r95_coverage_ci90"), 100.0, 1)
                    if x.get("r95_coverage") is not None else "–" for x in s)],
                 ["median of journeys' abs error slope (m per 100 m)",
                  *(fmt(x.get("slope_m_per_100m"), 3) for x in s)]]
        for kind, label in (("oxts", "OXTS-like GPS"), ("phone", "phone-like GPS")):
            g = [x["by_gps"][kind] for x in s]
            rows += [[f"{label}: journeys / signs", *(f"{y['n_journeys']} / {y['n_sign_errors']}"
                                                      for y in g)],
                     [f"{label}: abs median / p90 (m); GPS white σ median (m)",
                      *(f"{fmt(y.get('sign_abs_median_m'), 3)} / {fmt(y.get('sign_abs_p90_m'), 3)}"
                        f"; {fmt(y.get('gps_white_median_m'), 2)}" for y in g)],
                     [f"{label}: rel mean (m); inside 95 % radius; slope (m/100 m)",
                      *(f"{fmt(y.get('rel_mean_m'), 3)}{_interval(y.get('rel_mean_ci90_m'), 1.0, 3)}; "
                        + (f"{fmt(100 * y['r95_coverage'], 1)} % of {y['n_covered_of']}"
                           + _interval(y.get("r95_coverage_ci90"), 100.0, 1)
                           if y.get("r95_coverage") is not None else "–")
                        + f"; {fmt(y.get('slope_m_per_100m'), 3)}" for y in g)],
                     [f"{label}: slope pooled within journeys ± s.e. (m/100 m)",
                      *(f"{fmt(y.get('slope_pooled_m_per_100m'), 3)} ± "
                        f"{fmt(y.get('slope_pooled_se_m_per_100m'), 3)}" for y in g)]]
    return rows


def _interval(ci: list[float] | None, scale: float, digits: int) -> str:
    return "" if not ci else f" [{fmt(scale * ci[0], digits)}-{fmt(scale * ci[1], digits)}]"


def table_sigma(report: dict) -> str:
    """Accepted calibrations and their misses per bin of stage 2's own sigma (``own_sigmas``)."""
    s = [report["summary"][h]["by_sigma"] for h in HALVES]
    rows = [[tuning[0], *(f"{n}, {m}" if n else "–" for _, n, m in (tuning, check))]
            for tuning, check in zip(*s)]
    if not any(n for half in s for _, n, _ in half):
        return "### Misses by stage 2's own sigma\n\nNo accepted calibration with a covariance."
    return ("### Misses by stage 2's own sigma\n\nAccepted calibrations with stage 2's covariance, "
            "and of them how many miss the bar's fx/fy part (focal rows) or its k1 part (k1 rows), "
            "per bin of that covariance's sigma.\n\n"
            + md_table(["bin", *(f"{h}: accepted, missed" for h in HALVES)], rows))


def table_failures(report: dict) -> str:
    rows = [[g["reason"].replace("|", "/"), *(str(g.get(h, 0)) for h in HALVES),
             ", ".join(g["names"][:4]) + (" …" if len(g["names"]) > 4 else "")]
            for g in report["failures"]]
    if not rows:
        return "### Failure reasons\n\nNone."
    return ("### Failure reasons\n\nFailed journeys per normalised reason (numbers replaced; a "
            "journey counts once per distinct reason of its candidate windows).\n\n"
            + md_table(["reason", *HALVES, "journeys"], rows))


def table_params(report: dict) -> str:
    p = report["params"]
    num = [[k, *(fmt(v.get(h, {}).get(o), 2) for h in HALVES for o in ("failed", "accepted"))]
           for k, v in p["numeric"].items()]
    cat = [[k, *(f"{c['failed']}/{c['n']}" if (c := v.get(h)) else "–" for h in HALVES)]
           for k, v in sorted(p["categorical"].items())]
    return ("### What the failures share\n\nMedian of each numeric parameter over the failed and "
            "the accepted journeys:\n\n"
            + md_table(["parameter", *(f"{h} {o}" for h in HALVES for o in ("failed", "accepted"))],
                       num)
            + "\n\nFailed / decided journeys per value:\n\n"
            + md_table(["parameter = value", *HALVES], cat))


def table_clock(report: dict) -> str:
    """The camera clock errors of a video run; "" for a frames run."""
    c = report.get("clock")
    if not c:
        return ""
    reason = (f" (commonest: {c['commonest_reason'].replace('|', '/')}, "
              f"{c['commonest_reason_n']})" if c["n_not_estimated"] else "")
    rows = [["offset estimated", f"{c['n_estimated']}/{c['n']}"],
            ["\\|error\\| median / p90 / max (s)",
             " / ".join(fmt(c[k], 2) for k in ("abs_error_median_s", "abs_error_p90_s",
                                                "abs_error_max_s"))],
            [f"within {CLOCK_CLOSE_S:g} s", f"{c['n_within_close']}/{c['n_estimated']}"],
            ["not estimated", f"{c['n_not_estimated']}{reason}"]]
    return ("### Camera clock (video bundles)\n\nEach journey ran as a dash cam's video bundle, "
            "its camera clock off GPS time by a whole number of seconds (undeclared); error = "
            "the estimated clock error minus the true one.\n\n"
            + md_table(["", "journeys"], rows))


def table_journeys(report: dict) -> str:
    rows = []
    for r in sorted(report["journeys"], key=lambda r: (r.get("half") != "tuning", r["name"])):
        p = r["params"]
        result = outcome(r) + (" **WRONG**" if is_wrong(r) else "")
        reason = "" if r["status"] == "ok" else "; ".join(failure_reasons(r.get("error")))[:70]
        rows.append([r["name"], r.get("half"), fmt(p.get("fps"), 0), fmt(p.get("speed_mps"), 1),
                     f"{p.get('width', '?')}×{p.get('height', '?')}", fmt(param(r, "hfov_deg"), 0),
                     fmt(p.get("k1"), 3), fmt(p.get("max_turn_deg"), 0), result,
                     fmt(error(r, "fx_pct"), 2), fmt(error(r, "cy_px"), 1),
                     fmt(error(r, "k1_pct"), 1), fmt(error(r, "distortion_px"), 1),
                     fmt(r.get("calib_s"), 1),
                     reason.replace("|", "/")])
    header = ["journey", "half", "fps", "speed m/s", "W×H", "hfov °", "k1", "max turn °", "result",
              "fx %", "cy px", "k1 %", "dist. px", "calib s", "reason"]
    return "### Journeys\n\n" + md_table(header, rows)


def _table_range(report: dict) -> str:
    return table_range(report["by_range"]) if "by_range" in report else ""


def _table_antenna(report: dict) -> str:
    return table_antenna(report.get("antenna"))


def _table_broken(report: dict) -> str:
    return table_broken(report["broken"]) if "broken" in report else ""


def render_markdown(report: dict) -> str:
    m = report["meta"]
    head = (f"# Signmap corpus bench {m.get('date')}{' ' + m['tag'] if m.get('tag') else ''}\n\n"
            f"Corpus `{m.get('corpus')}` (seed {m.get('corpus_seed')}, n {m.get('corpus_n')}, "
            f"generator {m.get('generator_version')}); commit {m.get('commit')}"
            f"{' with uncommitted changes' if m.get('uncommitted_changes') else ''}, "
            f"{m.get('cpus')} CPUs, pycolmap {m.get('pycolmap')}; "
            f"{'calibration only; ' if m.get('calibrate_only') else ''}"
            f"{'as dash cam video bundles; ' if m.get('as_video') else ''}"
            f"{'antenna offsets undeclared; ' if m.get('antenna_undeclared') else ''}"
            f"{'a run of GPS fixes moved off (--gps-jump); ' if m.get('gps_jump') else ''}"
            f"knobs set: {json.dumps(m.get('config_overrides') or {})}; "
            f"this run {fmt(m.get('wall_s'), 0)} s. {BAR_TEXT}\n\n")
    tables = (table_summary, _table_range, _table_broken, _table_antenna, table_sigma,
              table_failures, table_clock, table_params, table_journeys)
    return head + "\n\n".join(text for t in tables if (text := t(report))) + "\n"


def render_records(records: list[dict], sources: list[str]) -> str:
    """The report's tables (not the journey list) over runs already made, pooled; a journey in
    more than one run keeps its last record, so a later re-run of a journey replaces it."""
    last = {r["name"]: r for r in records}
    report = build_report({}, list(last.values()))
    head = (f"# Signmap corpus records, re-read\n\n{len(last)} journeys from "
            + ", ".join(f"`{s}`" for s in sources)
            + (f" ({len(records) - len(last)} earlier records of the same journeys left out)"
               if len(records) > len(last) else "")
            + f". {BAR_TEXT}\n\n")
    tables = (table_summary, table_sigma, table_failures, table_clock)
    return head + "\n\n".join(text for t in tables if (text := t(report))) + "\n"


def plot_corpus(records: list[dict], png: Path) -> Path:
    """|fx error %| (log) against the largest turn and the horizontal field of view; failed
    calibrations drawn at the top as crosses."""
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2), sharey=True)
    errs = [abs(e) for r in records if (e := error(r, "fx_pct")) is not None]
    top = max([10.0, *errs]) * 2.0
    for ax, key, label in ((axes[0], "max_turn_deg", "largest turn (°)"),
                           (axes[1], "hfov_deg", "horizontal field of view (°)")):
        for half, color in zip(HALVES, ("tab:blue", "tab:orange")):
            rows = [r for r in records if r.get("half") == half and param(r, key) is not None]
            ok = [r for r in rows if outcome(r) == "accepted" and error(r, "fx_pct") is not None]
            bad = [r for r in rows if outcome(r) == "failed"]
            ax.plot([param(r, key) for r in ok],
                    [max(abs(error(r, "fx_pct")), 1e-3) for r in ok], "o", color=color,
                    ms=5, mfc="none", label=f"{half}: accepted")
            ax.plot([param(r, key) for r in bad], [top] * len(bad), "x", color=color,
                    ms=7, label=f"{half}: failed (drawn at the top)")
        ax.axhline(BAR["fx_pct"], color="tab:green", lw=0.8, ls="--", label="bar 1 %")
        ax.axhline(WRONG_FOCAL_PCT, color="tab:red", lw=0.8, ls=":", label="wrong > 3 %")
        ax.set_yscale("log")
        ax.set_xlabel(label)
        ax.grid(True, lw=0.3, which="both")
    axes[0].set_ylabel("|fx error| (%)")
    axes[0].legend(fontsize=7, loc="lower left")
    fig.suptitle("Self-calibration: focal length error per corpus journey")
    return save_figure(fig, png)


def write_report(meta: dict, records: list[dict], md_path: Path, json_path: Path, png: Path,
                 wall_s: float) -> str:
    """Write the markdown, JSON and PNG; return the markdown."""
    report = build_report({**meta, "wall_s": round(wall_s, 1), "plot": png.name}, records)
    md = render_markdown(report)
    md_path.write_text(md)
    json_path.write_text(json.dumps(finite(report), indent=1, allow_nan=False))
    plot_corpus(records, png)
    return md
