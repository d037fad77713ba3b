"""``signmap bench fleet``: issue 66's tables on a fleet corpus (``signmap synth corpus
--cameras``): each journey calibrated alone, and each camera calibrated jointly from its
journeys (``steps.calibrate_jointly``) beside the consensus the service kept before it (the mean
of the largest group of agreeing calibrations), in the same run.

Each journey's self-calibration runs once (``--calibrate-only``'s pipeline, in a fresh process)
and is kept in ``--keep DIR`` as ``<name>.npz`` (its accepted window's reconstruction) and
``<name>.json`` (the calibration or the error), so the joint fits can be run again, with other
knobs, in minutes.
"""

from __future__ import annotations

import json
import tempfile
from datetime import date
from pathlib import Path

import numpy as np

from app.pipeline.steps.calibrate_jointly import (CameraWindow, calibrate_jointly,
                                                  largest_agreeing)
from app.pipeline.types import CameraModel, WindowObservations
from bench.corpus.fleet_report import render_markdown
from bench.corpus.report import STEEP_TURN_DEG
from bench.corpus.run import (camera_errors, load_corpus, log, pipeline_config,
                              select_journeys)
from bench.paper.run_pipeline import RunTask, run_isolated


def calibrate_alone(corpus_dir: Path, entry: dict, keep_dir: Path) -> dict:
    """The journey's own self-calibration (kept in ``keep_dir``; run when not kept yet)."""
    name = entry["name"]
    record_path = keep_dir / f"{name}.json"
    if record_path.exists():
        return json.loads(record_path.read_text())
    jdir = Path(corpus_dir) / entry.get("dir", name)
    with tempfile.TemporaryDirectory(prefix=f"bench-fleet-{name}-") as tmp:
        task = RunTask(name, jdir / "bundle.zip", Path(tmp),
                       pipeline_config({}).model_dump(), calibrate_only=True)
        try:
            out = run_isolated(task)
            error, result = out.error, out.result
        except Exception as exc:  # noqa: BLE001 - a crash in the child is a failed record
            error, result = f"{type(exc).__name__}: {exc}", None
    record = {"name": name, "camera_id": entry["params"]["camera_id"],
              "index": entry["params"]["journey_index"], "half": entry["half"], "error": error}
    cal = result.calibration if result is not None else None
    if cal is not None and cal.source == "self" and cal.observations is not None:
        record.update(camera=cal.camera.params(), intrinsics_std=list(cal.intrinsics_std),
                      width=cal.camera.width, height=cal.camera.height)
        np.savez_compressed(keep_dir / f"{name}.npz", **cal.observations.arrays())
    tmp_path = record_path.with_suffix(".part")
    tmp_path.write_text(json.dumps(record, indent=1))
    tmp_path.replace(record_path)
    return record


def _window(record: dict, keep_dir: Path) -> CameraWindow:
    camera = CameraModel.from_params(record["width"], record["height"], record["camera"])
    with np.load(keep_dir / f"{record['name']}.npz") as arrays:
        observations = WindowObservations.from_arrays(arrays)
    return CameraWindow(record["name"], camera, observations, tuple(record["intrinsics_std"]))


def _consensus(windows: list[CameraWindow], agree_rel: float) -> CameraModel:
    group = [windows[i].camera for i in largest_agreeing(windows, agree_rel)]
    mean = np.mean([[c.fx, c.fy, c.cx, c.cy, c.k1, c.k2] for c in group], axis=0)
    return CameraModel(group[0].width, group[0].height, *map(float, mean))


def camera_rows(records: list[dict], true: dict, keep_dir: Path, agree_rel: float) -> list[dict]:
    """For one camera, after each of its journeys (in order): the joint calibration and the
    consensus of those calibrated so far, with their errors against ``true``."""
    rows, windows = [], []
    for record in records:
        if not record.get("camera"):
            continue  # no new window: the camera stays as it was
        windows.append(_window(record, keep_dir))
        joint = calibrate_jointly(windows, agree_rel=agree_rel)
        consensus = _consensus(windows, agree_rel)
        rows.append({"camera_id": record["camera_id"], "after": record["index"] + 1,
                     "windows": len(windows), "used": joint.used, "left_out": joint.left_out,
                     "joint": joint.camera.params(), "sigma": joint.sigma,
                     "fy_resolved": joint.fy_resolved,
                     "true": {k: float(true[k]) for k in ("fx", "fy", "cx", "cy", "k1", "k2")},
                     "joint_errors": camera_errors(joint.camera.params(), true),
                     "consensus_errors": camera_errors(consensus.params(), true)})
    return rows


def run_fleet(corpus_dir: Path, out_dir: Path, keep_dir: Path, *, half: str | None = None,
              agree_rel: float = 0.03, tag: str = "") -> Path:
    index = load_corpus(corpus_dir)
    entries = select_journeys(index, half=half)
    keep_dir.mkdir(parents=True, exist_ok=True)
    journeys = []
    for k, entry in enumerate(entries, start=1):
        record = calibrate_alone(corpus_dir, entry, keep_dir)
        true = entry["params"]
        # Issue 11's "turning journeys", as the corpus bench counts them.
        record["turns"] = (true.get("max_turn_deg") or 0.0) >= STEEP_TURN_DEG
        record["errors"] = camera_errors(record["camera"], true) if record.get("camera") else None
        journeys.append(record)
        log(f"[{k}/{len(entries)}] {entry['name']}: "
            + (f"fx {record['errors']['fx_pct']:+.2f} %" if record["errors"]
               else (record["error"] or "no calibration")[:100]))
    cameras = {}
    for record in journeys:
        cameras.setdefault(record["camera_id"], []).append(record)
    history = []
    for camera_id, records in cameras.items():
        true = next(e["params"] for e in entries if e["params"]["camera_id"] == camera_id)
        history += camera_rows(sorted(records, key=lambda r: r["index"]), true, keep_dir,
                               agree_rel)
        log(f"{camera_id}: {history[-1]['joint_errors'] if history else 'no calibration'}")
    report = {"corpus": str(corpus_dir), "half": half, "agree_rel": agree_rel,
              "journeys": journeys, "history": history}
    out_dir.mkdir(parents=True, exist_ok=True)
    stem = f"{date.today().isoformat()}-fleet{'-' + tag if tag else ''}"
    (out_dir / f"{stem}.json").write_text(json.dumps(report, indent=1))
    md = out_dir / f"{stem}.md"
    md.write_text(render_markdown(report))
    return md
