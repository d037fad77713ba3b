"""What ``signmap process`` prints while it runs and the JSON report it writes (the command itself
is ``app.commands.process``)."""

from __future__ import annotations

import math
import sys
import time
from typing import Sequence

from app.pipeline.types import INTRINSICS_STD, JourneyResult, StageReport


def _progress_printer(stream=None):
    """``stream`` None: sys.stderr as it is at each line (not as it was at import)."""
    t0 = time.perf_counter()

    def progress(stage: str, fraction: float, message: str = "") -> None:
        print(f"[{time.perf_counter() - t0:6.1f}s] {fraction * 100:5.1f}%  {stage:<12} {message}",
              file=stream or sys.stderr, flush=True)
    return progress


def report(result: JourneyResult, warnings: Sequence[str] = ()) -> dict:
    """The human/machine-readable summary written beside the GeoJSON; ``warnings``: the bundle's
    (``Journey.warnings``)."""
    cal = result.calibration
    return {
        "warnings": list(warnings),
        "calibration": {"source": cal.source, **cal.camera.params(),
                        "stage1": cal.stage1.params() if cal.stage1 else None,
                        # "checked": what the journey's turn measured of the camera it used.
                        "measured": cal.measured.params() if cal.measured else None,
                        "n_images": cal.n_images, "n_registered": cal.n_registered,
                        "reprojection_error_px": cal.reprojection_error_px,
                        "rotation_deg": cal.rotation_deg, "windows": cal.windows,
                        # Stage 2's own standard deviations (None: not given). Real errors on the
                        # corpus run about 2-3x these at the median, 4-11x at p90
                        # (docs/decisions/calib-misses.md).
                        "stage2_std": {k: (v if math.isfinite(v) else None)
                                       for k, v in zip(INTRINSICS_STD, cal.intrinsics_std)}},
        "timings_s": result.timings_s,
        "stage_parts_s": result.stage_parts_s,
        "signs": [{"track_id": s.track_id, "class": s.cls, "lat": s.lat_deg, "lon": s.lon_deg,
                   "alt_m": s.alt_m, "std_m": s.std_m, "r95_h_m": s.r95_h_m,
                   "facing_deg": s.facing_deg, "reprojection_rms_px": s.reprojection_rms_px,
                   "n_frames": len(s.observations)} for s in result.signs],
        "rejected": [{"track_id": r.track_id, "class": r.cls, "reason": r.reason}
                     for r in result.rejected],
        "report": [r.to_json() for r in result.report],
    }


# Details worth a line on the terminal too (the rest are in the JSON report): where the GPS
# positions were moved from, which moves every sign.
SHOWN_DETAILS = ("GPS antenna offset",)


def stage_summary(reports: Sequence[StageReport], stream=None) -> None:
    """One line per stage that ran: what it found or why it failed, and its SHOWN_DETAILS
    (``stream`` None: stdout)."""
    for r in reports:
        print(f"{r.stage:<12} {r.summary}", file=stream or sys.stdout)
        for line in r.details:
            if line.startswith(SHOWN_DETAILS):
                print(f"{'':<12} {line}", file=stream or sys.stdout)
