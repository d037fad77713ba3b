"""Windows that disagreed with the GPS (``JourneyResult.broken_windows``): how many broke, were
mended or lost, and the signs each cost or kept (issue 67's broken-window bar: on the check half
at most 1 mappable sign in 50 lost to such a window)."""

from __future__ import annotations

import csv
import hashlib
import io
import zipfile
from pathlib import Path

import numpy as np

from bench.corpus.by_range import HALVES
from bench.paper.tables import fmt, md_table

LOST_REASON = "disagrees with the GPS"  # place_signs.check_reconstruction's reason
EARTH_M_PER_DEG = 111_320.0  # a degree of latitude; metres of a few-metre jump need no better


def broken_record(result) -> list[dict]:
    """A run's broken windows, as its corpus record keeps them."""
    return [{"frames": [b.first_frame, b.last_frame], "rms_m": round(b.rms_m, 3),
             "limit_m": round(b.limit_m, 3), "mended": b.mended, "how": b.how,
             "tracks": list(b.track_ids)} for b in result.broken_windows]


def broken_summary(records: list[dict]) -> dict:
    """Per half: windows broken, mended, lost; mappable signs lost to a disagreeing window; signs
    placed from a mended window and their error."""
    out = {}
    for half in HALVES:
        mine = [r for r in records if r.get("half") == half and r.get("signs")]
        windows = [w for r in mine for w in r.get("broken_windows", [])]
        kept = [r["sign_errors"][t]["abs_m"] for r in mine
                for w in r.get("broken_windows", []) if w["mended"]
                for t in w["tracks"] if t in r.get("sign_errors", {})]
        out[half] = {
            "n_journeys": len(mine),
            "n_broken": len(windows), "n_mended": sum(w["mended"] for w in windows),
            "n_mappable": sum(r["signs"]["n_mappable"] for r in mine),
            "n_lost": sum(LOST_REASON in why for r in mine
                          for why in r.get("missed_mappable", {}).values()),
            "n_kept": len(kept),
            "kept_abs_median_m": float(np.median(kept)) if kept else None,
            "journeys": sorted({r["name"] for r in mine if r.get("broken_windows")})}
    return out


def table_broken(summary: dict) -> str:
    """Markdown: the broken-window counts per half, and each broken window's fate."""
    rows = [[label, *(str(summary[h][key]) for h in HALVES)] for label, key in (
        ("journeys with signs", "n_journeys"), ("windows broken (GPS rms over the limit)",
                                                "n_broken"),
        ("of them mended", "n_mended"), ("mappable signs", "n_mappable"),
        ("mappable signs lost to a window that disagrees with the GPS", "n_lost"),
        ("signs placed from a mended window", "n_kept"))]
    rows.append(["their abs error median (m)",
                 *(fmt(summary[h]["kept_abs_median_m"], 3) for h in HALVES)])
    rows.append(["journeys", *(", ".join(summary[h]["journeys"]) or "–" for h in HALVES)])
    return ("### Windows that disagree with the GPS\n\nA window whose own alignment lies further "
            "from the GPS than the limit (5 x its noise, at least 1 m) is mended where a run of "
            "bad fixes explains it (`steps.align.mend`); what is left broken loses its signs."
            "\n\n" + md_table(["", *HALVES], rows))


def gps_jump_of(name: str) -> dict:
    """The multipath jump a journey's GPS gets with ``--gps-jump``, drawn from its name (every
    run and machine the same): a run of 1.5-3 s starting 30-60 % of the way through its fixes,
    4-10 m off in one horizontal direction, as fixes are by a tall building's reflection."""
    rng = np.random.default_rng(int(hashlib.sha256(name.encode()).hexdigest()[:16], 16))
    return {"start_share": float(rng.uniform(0.3, 0.6)), "length_s": float(rng.uniform(1.5, 3.0)),
            "offset_m": float(rng.uniform(4.0, 10.0)),
            "bearing_deg": float(rng.uniform(0.0, 360.0))}


def with_gps_jump(bundle: Path, out: Path, jump: dict) -> dict:
    """``bundle`` copied to ``out`` with ``jump`` (as ``gps_jump_of`` draws it) added to its
    gps.csv fixes; the jump as applied (its start and the fixes it moved)."""
    with zipfile.ZipFile(bundle) as src:
        if "gps.csv" not in src.namelist():
            raise ValueError(f"{bundle}: --gps-jump moves gps.csv fixes, and it has no gps.csv")
        rows = list(csv.DictReader(io.StringIO(src.read("gps.csv").decode())))
        t_fix = [float(r["timestamp_s"]) for r in rows if r["lat"]]
        if len(t_fix) < 2:
            raise ValueError(f"{bundle}: fewer than two GPS fixes to move")
        start_s = t_fix[0] + jump["start_share"] * (t_fix[-1] - t_fix[0])
        bearing = np.radians(jump["bearing_deg"])
        east_m, north_m = jump["offset_m"] * np.sin(bearing), jump["offset_m"] * np.cos(bearing)
        moved = 0
        for r in rows:
            if r["lat"] and start_s <= float(r["timestamp_s"]) < start_s + jump["length_s"]:
                lat = float(r["lat"])
                lon_m_per_deg = EARTH_M_PER_DEG * np.cos(np.radians(lat))
                r["lat"] = f"{lat + north_m / EARTH_M_PER_DEG:.9f}"
                r["lon"] = f"{float(r['lon']) + east_m / lon_m_per_deg:.9f}"
                moved += 1
        text = io.StringIO()
        writer = csv.DictWriter(text, fieldnames=list(rows[0]), lineterminator="\n")
        writer.writeheader()
        writer.writerows(rows)
        with zipfile.ZipFile(out, "w") as dst:
            for info in src.infolist():
                dst.writestr(info, text.getvalue().encode() if info.filename == "gps.csv"
                             else src.read(info))
    return {**jump, "start_s": round(start_s, 3), "n_fixes_moved": moved}
