"""Print a `signmap process` report's signs and calibration against a synthetic journey's truth.

    python -m bench.compare signs.report.json truth.json
"""

from __future__ import annotations

import json
import sys

import numpy as np

from app.pipeline.geometry.geodesy import frame_at
from bench.paper.metrics import calibration_errors_pct


def main(report_path: str, truth_path: str) -> int:
    report = json.loads(open(report_path).read())
    truth = json.loads(open(truth_path).read())
    errors = calibration_errors_pct(report["calibration"], truth)
    print("calibration error vs truth: "
          + ", ".join(f"{k} {v:+.2f}%" for k, v in errors.items()))
    o = truth["origin"]
    enu = frame_at(o["lat"], o["lon"], o["alt_m"])
    true_by_track = {str(s["track_id"]): np.asarray(s["xyz_enu"]) for s in truth["signs"]}
    abs_m = []
    for s in report["signs"]:
        est = enu.to_local([s["lat"]], [s["lon"]], [s["alt_m"]])[0]
        err = float(np.linalg.norm(est - true_by_track[s["track_id"]]))
        abs_m.append(err)
        print(f"sign {s['track_id']:>4} {s['class']:<16} error {err:5.2f} m  (±{s['std_m']:.2f} m)")
    if abs_m:
        print(f"{len(abs_m)}/{len(truth['signs'])} signs, absolute error median "
              f"{np.median(abs_m):.2f} m, max {np.max(abs_m):.2f} m")
    return 0


if __name__ == "__main__":
    sys.exit(main(*sys.argv[1:3]))
