"""``signmap bench sensitivity``: the paper's one-at-a-time study (its Fig. 3).

The pipeline is given a camera with an error of -15 % ... +15 % in one group of parameters (focal
lengths, principal point, distortion coefficients; the others at their true values) as the known
calibration of the journey, and the sign errors are measured.
"""

from __future__ import annotations

import datetime as dt
import json
import tempfile
from pathlib import Path

import numpy as np

from app.pipeline.types import CameraModel
from bench.paper import plots
from bench.paper.metrics import mappable_signs
from bench.paper.run_pipeline import RunTask, run_isolated
from bench.paper.runner import finite, log, run_summary
from bench.paper.suite import ensure_journey, sensitivity_journey
from bench.paper.tables import fmt, md_table

GROUPS = {"focal length": ("fx", "fy"), "principal point": ("cx", "cy"),
          "distortion": ("k1", "k2")}


def perturbed_cameras(camera: CameraModel, steps_pct: list[float]) -> list[tuple[str, float,
                                                                               CameraModel]]:
    """(group, error %, camera) for every group and non-zero step, and ("none", 0, camera) once
    when 0 is a step: the true camera is the same point of every curve."""
    out = [("none", 0.0, camera)] if 0.0 in steps_pct else []
    for group, keys in GROUPS.items():
        for pct in steps_pct:
            if pct != 0.0:
                scale = 1.0 + pct / 100.0
                out.append((group, pct, camera.replace(
                    **{k: getattr(camera, k) * scale for k in keys})))
    return out


def sensitivity_rows(runs: list[tuple[str, float, dict]]) -> list[dict]:
    """Flatten (group, error %, run record) to one row per curve point; the true camera's run
    ("none") becomes the 0 % point of every group."""
    rows = []
    for group, pct, run in runs:
        for g in (GROUPS if group == "none" else [group]):
            signs = run.get("signs", {})
            rows.append({"group": g, "error_pct": pct, "status": run["status"],
                         "error": run.get("error"), "n_signs": signs.get("n_signs", 0),
                         "rel_mean_m": signs.get("rel_mean_m"),
                         "abs_mean_m": signs.get("abs_mean_m"),
                         "ate_gps_m": run.get("ate", {}).get("ate_gps_m")})
    return rows


def table_sensitivity(report: dict) -> str:
    rows = [[r["group"], f"{r['error_pct']:+.1f}", f"{r['n_signs']} / {report['n_signs_mappable']}",
             fmt(r["rel_mean_m"]), fmt(r["abs_mean_m"]), fmt(r["ate_gps_m"]),
             r["status"] if r["status"] == "ok" else f"{r['status']}: {r['error']}"]
            for r in sorted(report["rows"], key=lambda r: (r["group"], r["error_pct"]))]
    header = ["parameters", "error %", "signs / mappable", "rel mean (m)", "abs mean (m)",
              "ATE as georeferenced (m)", "run"]
    return md_table(header, rows)


def run_sensitivity(*, quick: bool, out_dir: Path, cache_dir: Path,
                    steps: int = 5) -> tuple[Path, Path]:
    """Run the study; write ``<date>-sensitivity[-quick].md`` / ``.json`` / ``.png``."""
    from app.settings import Settings

    spec = sensitivity_journey(quick)
    bundle, truth = ensure_journey(spec, cache_dir)
    cam = truth["camera"]
    camera = CameraModel.from_params(cam["width"], cam["height"], cam)
    config = Settings().pipeline.model_copy(update={"reuse_known_calibration": True})
    config_d = config.model_dump()
    steps_pct = [float(p) for p in np.linspace(-15.0, 15.0, 3 if quick else steps)]
    runs = []
    for group, pct, wrong in perturbed_cameras(camera, steps_pct):
        label = f"{spec.name}/{group} {pct:+.1f}%"
        log(f"{label}: running")
        with tempfile.TemporaryDirectory(prefix="bench-sens-") as tmp:
            task = RunTask(label, bundle, Path(tmp), config_d, known_camera=wrong)
            out = run_isolated(task)
            runs.append((group, pct, run_summary(out, truth, task)))
        log(f"{label}: {runs[-1][2]['status']} in {out.wall_s:.0f} s")
    stem = dt.date.today().isoformat() + "-sensitivity" + ("-quick" if quick else "")
    report = {"date": dt.date.today().isoformat(), "journey": spec.name,
              "description": spec.description, "alignment": config.alignment,
              "n_signs_mappable": mappable_signs(truth, config.min_track_frames),
              "steps_pct": steps_pct, "rows": sensitivity_rows(runs)}
    out_dir.mkdir(parents=True, exist_ok=True)
    png = plots.plot_sensitivity(report["rows"], list(GROUPS), out_dir / f"{stem}.png")
    md = (f"# Sensitivity to camera errors {report['date']}\n\nJourney {spec.name}: "
          f"{spec.description}. The pipeline is given the camera with the error as its known "
          f"calibration ({config.alignment} alignment); other parameters at their true values. "
          f"Plot: `{png.name}`.\n\n" + table_sensitivity(report) + "\n")
    md_path, json_path = out_dir / f"{stem}.md", out_dir / f"{stem}.json"
    md_path.write_text(md)
    json_path.write_text(json.dumps(finite(report), indent=1, allow_nan=False))
    return md_path, json_path
