"""``signmap bench fleet``: issue 66's tables on a fleet corpus (``signmap synth corpus
--cameras``): each journey calibrated alone, and each camera calibrated jointly from its
journeys (``cameras.calibrate_jointly``) beside the consensus the service kept before it (the mean
of the largest group of agreeing calibrations), in the same run.

Each journey's self-calibration runs once (``--calibrate-only``'s pipeline, in a fresh process)
and is kept in ``--keep DIR`` as ``<name>.npz`` (its accepted window's reconstruction) and
``<name>.json`` (the calibration or the error), so the joint fits can be run again, with other
knobs, in minutes.

Each camera's second journey with a turn is also run given the camera's calibration after its
first (``cameras.check_on_turn``: the stored camera checked on the turn), beside its own
self-calibration above: time and outcome side by side (``<name>.check.json`` in ``--keep``).

With ``again``, every journey of each camera is run in full twice: with its true camera, and as
the service processes it again once the camera is fitted from all its journeys (the joint
calibration as the camera's stored one: checked on a turn, used as it is without one); kept as
``<name>.true.json`` and ``<name>.again.json`` (issue 66's "processed again" bar).
"""

from __future__ import annotations

import json
import tempfile
from datetime import date
from pathlib import Path

import numpy as np

from app.pipeline.cameras.calibrate_jointly import (CameraWindow, calibrate_jointly,
                                                  largest_agreeing)
from app.pipeline.types import CameraModel, WindowObservations
from bench.corpus.fleet_report import render_markdown
from bench.corpus.report import STEEP_TURN_DEG
from bench.corpus.run import (camera_errors, load_corpus, log, pipeline_config, run_journey,
                              select_journeys)
from bench.paper.metrics import distortion_error_px, true_camera
from bench.paper.run_pipeline import RunTask, run_isolated


def _calibrate(corpus_dir: Path, entry: dict, known: CameraModel | None = None):
    """``entry``'s journey run up to its calibration (in a fresh process), given the camera
    ``known``: (error, result, calibrate stage seconds)."""
    name = entry["name"]
    jdir = Path(corpus_dir) / entry.get("dir", name)
    with tempfile.TemporaryDirectory(prefix=f"bench-fleet-{name}-") as tmp:
        task = RunTask(name, jdir / "bundle.zip", Path(tmp), pipeline_config({}).model_dump(),
                       calibrate_only=True, known_camera=known)
        try:
            out = run_isolated(task)
            return out.error, out.result, out.timings_s.get("calibrate")
        except Exception as exc:  # noqa: BLE001 - a crash in the child is a failed record
            return f"{type(exc).__name__}: {exc}", None, None


def calibrate_alone(corpus_dir: Path, entry: dict, keep_dir: Path) -> dict:
    """The journey's own self-calibration (kept in ``keep_dir``; run when not kept yet)."""
    name = entry["name"]
    record_path = keep_dir / f"{name}.json"
    if record_path.exists():
        return json.loads(record_path.read_text())
    error, result, calibrate_s = _calibrate(corpus_dir, entry)
    record = {"name": name, "camera_id": entry["params"]["camera_id"],
              "index": entry["params"]["journey_index"], "half": entry["half"], "error": error,
              "calibrate_s": calibrate_s}
    cal = result.calibration if result is not None else None
    if cal is not None and cal.source == "self" and cal.observations is not None:
        record.update(camera=cal.camera.params(), intrinsics_std=list(cal.intrinsics_std),
                      width=cal.camera.width, height=cal.camera.height)
        np.savez_compressed(keep_dir / f"{name}.npz", **cal.observations.arrays())
    tmp_path = record_path.with_suffix(".part")
    tmp_path.write_text(json.dumps(record, indent=1))
    tmp_path.replace(record_path)
    return record


def checked_second(corpus_dir: Path, entry: dict, first: dict, keep_dir: Path) -> dict:
    """``entry``'s journey given the calibration of ``first`` (the camera's first calibrated
    journey's record) as its camera's stored one (kept in ``keep_dir``)."""
    path = keep_dir / f"{entry['name']}.check.json"
    if path.exists():
        return json.loads(path.read_text())
    stored = CameraModel.from_params(first["width"], first["height"], first["camera"])
    error, result, calibrate_s = _calibrate(corpus_dir, entry, stored)
    cal = result.calibration if result is not None else None
    true = entry["params"]
    record = {"name": entry["name"], "first": first["name"], "error": error,
              "calibrate_s": calibrate_s, "source": cal.source if cal else None,
              "errors": camera_errors(cal.camera.params(), true) if cal else None,
              "turn_errors": (camera_errors(cal.turn_estimate.params(), true)
                              if cal is not None and cal.turn_estimate is not None else None),
              "summary": next((r.summary for r in result.report if r.stage == "calibrate"), "")
              if result is not None else "",
              # Why the check did not confirm the camera, when it did not.
              "not_confirmed": next((d for r in result.report if r.stage == "calibrate"
                                     for d in r.details if d.startswith("stored calibration")),
                                    None) if result is not None else None}
    path.write_text(json.dumps(record, indent=1))
    return record


def second_journeys(corpus_dir: Path, entries: list[dict], records: list[dict],
                    keep_dir: Path) -> list[dict]:
    """For one camera (``records`` in journey order): its first calibrated journey, and the
    next with a turn run both ways (its self-calibration, ``records``'; and checked)."""
    first = next((r for r in records if r.get("camera")), None)
    second = next((r for r in records
                   if first is not None and r["index"] > first["index"] and r["turns"]), None)
    if second is None:
        return []
    entry = next(e for e in entries if e["name"] == second["name"])
    return [{"camera_id": first["camera_id"], "first": first, "self": second,
             "checked": checked_second(corpus_dir, entry, first, keep_dir)}]


def _placement(record: dict) -> dict:
    """What the processed-again table reads of a full run's corpus record."""
    signs = record.get("signs") or {}
    return {"name": record["name"], "error": record["error"], "wall_s": record["wall_s"],
            "source": (record.get("calibration") or {}).get("source"),
            "mappable": signs.get("n_mappable", 0), "found": signs.get("n_mappable_found", 0),
            "false": signs.get("n_false", 0),
            "abs_m": [e["abs_m"] for e in (record.get("sign_errors") or {}).values()
                      if e.get("abs_m") is not None]}


def _same_camera(a: dict | None, b: dict | None) -> bool:
    """The same camera parameters, but for the last digits a joint fit run again changes."""
    if a is None or b is None:
        return a is b
    return a.keys() == b.keys() and all(np.isclose(a[k], b[k], rtol=1e-7, atol=1e-9) for k in a)


def processed_again(corpus_dir: Path, entries: list[dict], joint: CameraModel,
                    keep_dir: Path) -> dict:
    """One camera's journeys (``entries``) run in full with their true camera and given
    ``joint`` as the camera's stored calibration, each kept in ``keep_dir``."""
    runs: dict[str, list[dict]] = {"true": [], "again": []}
    for entry in entries:
        for way in runs:
            path = keep_dir / f"{entry['name']}.{way}.json"
            given = joint.params() if way == "again" else None
            kept = json.loads(path.read_text()) if path.exists() else None
            if kept is None or not _same_camera(kept.get("given"), given):  # another joint fit
                record = run_journey(corpus_dir, entry, pipeline_config({}), False,
                                     true_camera=way == "true", stored_camera=way == "again",
                                     camera=joint if way == "again" else None)
                kept = {**_placement(record), "given": given}
                path.write_text(json.dumps(kept, indent=1))
            runs[way].append(kept)
            log(f"{entry['name']} {way}: {kept['found']}/{kept['mappable']} signs, "
                f"{kept['source'] or kept['error']}")
    return runs


def _window(record: dict, keep_dir: Path) -> CameraWindow:
    camera = CameraModel.from_params(record["width"], record["height"], record["camera"])
    with np.load(keep_dir / f"{record['name']}.npz") as arrays:
        observations = WindowObservations.from_arrays(arrays)
    return CameraWindow(record["name"], camera, observations, tuple(record["intrinsics_std"]))


def _consensus(windows: list[CameraWindow], agree_rel: float) -> CameraModel:
    group = [windows[i].camera for i in largest_agreeing(windows, agree_rel)]
    mean = np.mean([[c.fx, c.fy, c.cx, c.cy, c.k1, c.k2] for c in group], axis=0)
    return CameraModel(group[0].width, group[0].height, *map(float, mean))


def seen_px(windows: list[CameraWindow], true: CameraModel) -> float:
    """How far from the principal point the windows' features reach: the 95th percentile of
    their observations' distance from it, px."""
    xy = np.concatenate([w.observations.xy_px for w in windows])
    return float(np.percentile(np.hypot(xy[:, 0] - true.cx, xy[:, 1] - true.cy), 95))


def camera_rows(records: list[dict], true: dict, keep_dir: Path, agree_rel: float) -> list[dict]:
    """For one camera, after each of its journeys (in order): the joint calibration and the
    consensus of those calibrated so far, with their errors against ``true``; and how far into
    the image the windows' features reach (``seen_px``, their 95th percentile distance from the
    principal point; ``corner_px``) with the joint distortion's error within that."""
    rows, windows = [], []
    true_cam = true_camera(true)
    corner_px = float(np.hypot(max(true_cam.cx, true_cam.width - 1 - true_cam.cx),
                               max(true_cam.cy, true_cam.height - 1 - true_cam.cy)))
    for record in records:
        if not record.get("camera"):
            continue  # no new window: the camera stays as it was
        windows.append(_window(record, keep_dir))
        joint = calibrate_jointly(windows, agree_rel=agree_rel)
        consensus = _consensus(windows, agree_rel)
        reach = seen_px(windows, true_cam)
        rows.append({"camera_id": record["camera_id"], "after": record["index"] + 1,
                     "windows": len(windows), "used": joint.used, "left_out": joint.left_out,
                     "joint": joint.camera.params(), "sigma": joint.sigma,
                     "fy_resolved": joint.fy_resolved,
                     "true": {k: float(true[k]) for k in ("fx", "fy", "cx", "cy", "k1", "k2")},
                     "joint_errors": camera_errors(joint.camera.params(), true),
                     "consensus_errors": camera_errors(consensus.params(), true),
                     "seen_px": reach, "corner_px": corner_px,
                     "distortion_seen_px": distortion_error_px(joint.camera.params(),
                                                               true_cam, within_px=reach)})
    return rows


def run_fleet(corpus_dir: Path, out_dir: Path, keep_dir: Path, *, half: str | None = None,
              agree_rel: float = 0.03, tag: str = "", again: bool = False) -> Path:
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
    history, seconds, reprocessed = [], [], []
    for camera_id, records in cameras.items():
        true = next(e["params"] for e in entries if e["params"]["camera_id"] == camera_id)
        ordered = sorted(records, key=lambda r: r["index"])
        rows = camera_rows(ordered, true, keep_dir, agree_rel)
        history += rows
        log(f"{camera_id}: {rows[-1]['joint_errors'] if rows else 'no calibration'}")
        seconds += second_journeys(corpus_dir, entries, ordered, keep_dir)
        if seconds and seconds[-1]["camera_id"] == camera_id:
            log(f"{camera_id} second journey checked: {seconds[-1]['checked']['summary'][:100]}")
        if again and rows:
            size = next(r for r in ordered if r.get("camera"))
            joint = CameraModel.from_params(size["width"], size["height"], rows[-1]["joint"])
            mine = [e for e in entries if e["params"]["camera_id"] == camera_id]
            reprocessed.append({"camera_id": camera_id,
                                **processed_again(corpus_dir, mine, joint, keep_dir)})
    report = {"corpus": str(corpus_dir), "half": half, "agree_rel": agree_rel,
              "journeys": journeys, "history": history, "second_journeys": seconds,
              "processed_again": reprocessed}
    out_dir.mkdir(parents=True, exist_ok=True)
    stem = f"{date.today().isoformat()}-fleet{'-' + tag if tag else ''}"
    (out_dir / f"{stem}.json").write_text(json.dumps(report, indent=1))
    md = out_dir / f"{stem}.md"
    md.write_text(render_markdown(report))
    return md
