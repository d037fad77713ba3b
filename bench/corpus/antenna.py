"""The GPS antenna offset a run estimated (its align report) against the true one (a corpus
rendered with ``--antenna-offsets`` and run with ``--antenna-undeclared``)."""

from __future__ import annotations

import re

import numpy as np

from app.pipeline.types import StageReport
from bench.paper.tables import fmt, md_table

HALVES = ("tuning", "check")
ESTIMATED = re.compile(r"GPS antenna offset estimated: forward ([-+][\d.]+) ± ([\d.]+) m, left "
                       r"([-+][\d.]+) ± ([\d.]+) m .*turning up to (\d+)°\); (applied|not applied)")
BAR_M = 0.2  # the report names the offset within this on turning journeys


def estimate_fields(reports: tuple[StageReport, ...] | list[StageReport]) -> dict:
    """What the align report says of an estimated offset: forward, left and their sigmas (m),
    the turn it came from, whether it was applied; {} when it says nothing of one."""
    for line in next((r.details for r in reports if r.stage == "align"), ()):
        if found := ESTIMATED.search(line):
            f, sf, lf, sl, turn, applied = found.groups()
            return {"antenna_est_m": [float(f), float(lf)],
                    "antenna_sigma_m": [float(sf), float(sl)],
                    "antenna_turn_deg": float(turn), "antenna_applied": applied == "applied"}
    return {}


def antenna_rows(records: list[dict]) -> list[dict]:
    """Per journey with a true offset: the true and estimated horizontal offset, the error and its
    size in sigmas (None where nothing was estimated)."""
    rows = []
    for r in records:
        true = (r.get("params") or {}).get("gps_antenna_offset_m")
        if true is None or r.get("status") != "ok":
            continue
        est = r.get("antenna_est_m")
        err = None if est is None else np.subtract(est, true[:2])
        sigma = r.get("antenna_sigma_m")
        rows.append({"name": r["name"], "half": r.get("half"), "true": true[:2], "est": est,
                     "error_m": None if err is None else float(np.hypot(*err)),
                     "z": (None if err is None else
                           float(np.max(np.abs(err) / np.maximum(sigma, 1e-9)))),
                     "sigma_m": None if sigma is None else max(sigma),
                     "applied": bool(r.get("antenna_applied")),
                     "turn_deg": r.get("antenna_turn_deg")})
    return rows


def antenna_summary(records: list[dict]) -> dict | None:
    """Per half: journeys with a true offset, estimated, within BAR_M, applied, applied and
    within BAR_M, median error; None when no record has a true offset."""
    rows = antenna_rows(records)
    if not rows:
        return None
    out = {}
    for half in HALVES:
        mine = [x for x in rows if x["half"] == half]
        est = [x for x in mine if x["error_m"] is not None]
        applied = [x for x in est if x["applied"]]
        out[half] = {"n": len(mine), "n_estimated": len(est),
                     "n_within": sum(x["error_m"] <= BAR_M for x in est),
                     "n_applied": len(applied),
                     "n_applied_within": sum(x["error_m"] <= BAR_M for x in applied),
                     "error_median_m": (float(np.median([x["error_m"] for x in est]))
                                        if est else None),
                     "z_median": float(np.median([x["z"] for x in est])) if est else None}
    return {"halves": out, "journeys": rows}


def table_antenna(summary: dict | None) -> str:
    """Markdown: the estimated offsets against the true ones; "" without true offsets."""
    if summary is None:
        return ""
    h = summary["halves"]
    rows = [[label, *(str(h[x][key]) for x in HALVES)] for label, key in (
        ("journeys with an undeclared offset", "n"), ("estimated", "n_estimated"),
        (f"estimated within {BAR_M:g} m", "n_within"), ("applied (sigma under the knob)",
                                                         "n_applied"),
        (f"applied and within {BAR_M:g} m", "n_applied_within"))]
    rows += [["median error of the estimates (m)", *(fmt(h[x]["error_median_m"], 3)
                                                    for x in HALVES)],
             ["median error / sigma (largest axis)", *(fmt(h[x]["z_median"], 2) for x in HALVES)]]
    journeys = [[x["name"], x["half"], "{:+.2f} {:+.2f}".format(*x["true"]),
                 "–" if x["est"] is None else "{:+.2f} {:+.2f}".format(*x["est"]),
                 fmt(x["sigma_m"], 2), fmt(x["error_m"], 2),
                 "yes" if x["applied"] else "no", fmt(x["turn_deg"], 0)]
                for x in summary["journeys"]]
    return ("### GPS antenna offset, undeclared\n\nThe horizontal offset (forward, left; m) each "
            "journey's windows told, against the one it was rendered with.\n\n"
            + md_table(["", *HALVES], rows) + "\n\n"
            + md_table(["journey", "half", "true", "estimated", "sigma", "error", "applied",
                        "turn °"], journeys))
