"""``signmap process BUNDLE.zip``: the whole pipeline locally, no server or database needed."""

from __future__ import annotations

import json
import logging
import sys
import tempfile
import time
from pathlib import Path
from typing import Sequence

from app.geojson import feature_collection, journey_sign_features
from app.pipeline.bundle import read_bundle
from app.pipeline.run import process_journey
from app.pipeline.types import CameraModel, JourneyResult, PipelineError


def _progress_printer(stream=sys.stderr):
    t0 = time.perf_counter()

    def progress(stage: str, fraction: float, message: str = "") -> None:
        print(f"[{time.perf_counter() - t0:6.1f}s] {fraction * 100:5.1f}%  {stage:<12} {message}",
              file=stream, flush=True)
    return progress


def report(result: JourneyResult, warnings: Sequence[str] = ()) -> dict:
    """The human/machine-readable summary written beside the GeoJSON; ``warnings``: the bundle's
    (``Journey.warnings``)."""
    cal = result.calibration
    return {
        "warnings": list(warnings),
        "calibration": {"source": cal.source, **cal.camera.params(),
                        "stage1": cal.stage1.params() if cal.stage1 else None,
                        "n_images": cal.n_images, "n_registered": cal.n_registered,
                        "reprojection_error_px": cal.reprojection_error_px,
                        "rotation_deg": cal.rotation_deg, "windows": cal.windows},
        "timings_s": result.timings_s,
        "signs": [{"track_id": s.track_id, "class": s.cls, "lat": s.lat_deg, "lon": s.lon_deg,
                   "alt_m": s.alt_m, "std_m": s.std_m, "reprojection_rms_px": s.reprojection_rms_px,
                   "n_frames": len(s.observations)} for s in result.signs],
        "rejected": [{"track_id": r.track_id, "class": r.cls, "reason": r.reason}
                     for r in result.rejected],
    }


def run_process(args) -> int:
    from app.settings import Settings

    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    settings = Settings()
    known = None
    out = Path(args.out)
    with tempfile.TemporaryDirectory(prefix="signmap-") as tmp:
        workdir = Path(args.workdir) if args.workdir else Path(tmp)
        try:
            journey = read_bundle(Path(args.bundle), workdir / "bundle")
            if args.calibration:
                params = json.loads(Path(args.calibration).read_text())
                known = CameraModel.from_params(journey.image_width, journey.image_height, params)
            result = process_journey(journey, settings.pipeline, workdir / "work",
                                     known_camera=known, progress=_progress_printer(),
                                     verbose=args.verbose)
        except PipelineError as exc:
            print(f"signmap: {exc}", file=sys.stderr)
            return 2
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(feature_collection(journey_sign_features(result.signs)), indent=1))
    report_path = Path(args.report) if args.report else out.with_suffix(".report.json")
    report_path.write_text(json.dumps(report(result, journey.warnings), indent=1))
    cal = result.calibration.camera
    print(f"calibration ({result.calibration.source}): fx={cal.fx:.1f} fy={cal.fy:.1f} "
          f"cx={cal.cx:.1f} cy={cal.cy:.1f} k1={cal.k1:.3f} k2={cal.k2:.3f}")
    for s in result.signs:
        alt = "" if s.alt_m is None else f" alt {s.alt_m:.2f} m"
        print(f"sign {s.track_id:>6} {s.cls:<16} lat {s.lat_deg:.7f} lon {s.lon_deg:.7f}{alt} "
              f"± {s.std_m:.2f} m ({len(s.observations)} frames)")
    for r in result.rejected:
        print(f"rejected {r.track_id}: {r.reason}")
    print(f"wrote {out} and {report_path}; stages: "
          + ", ".join(f"{k} {v:.1f}s" for k, v in result.timings_s.items()))
    return 0
