"""``signmap bench corpus``: the pipeline on every journey of a generated corpus (``signmap synth
corpus``), one JSON record per journey, one report (``bench.corpus.report``).

A corpus is many small journeys whose cameras, scenes and turns vary; ``corpus.json`` lists them
with their parameters and splits them into a "tuning" half (to choose knobs on) and a "check" half
(to confirm a choice on journeys it was not tuned on). Records are appended to a JSONL file as the
journeys finish, so a long run that dies keeps what it had and ``resume`` continues it.

``as_video``: each journey goes in as the video bundle a dash cam would upload
(docs/journey-format.md 1a) instead of its frames bundle, with a camera clock error the service
must estimate; its record says how well it did (``clock_error_s`` against ``clock_error_est_s``).
"""

from __future__ import annotations

import datetime as dt
import hashlib
import json
import re
import sys
import tempfile
import time
import zipfile
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from app.pipeline.bundle.associate import box_iou
from app.pipeline.config import PipelineConfig
from app.pipeline.types import CameraModel, JourneyResult, StageReport
from bench.corpus import antenna, replay
from bench.corpus.broken import broken_record, gps_jump_of, with_gps_jump
from bench.corpus import report as corpus_report
from bench.paper.metrics import (RECALL_MIN_FRAMES, calibration_summary, distortion_error_px,
                                 evaluate_result, mappable_ids, projection_error_px, true_camera,
                                 truth_id)
from bench.paper.run_pipeline import RunOutput, RunTask, detections_of, run_isolated
from bench.paper.runner import finite, run_meta  # commit, machine, pycolmap: as the other benches

CORPUS_FORMAT = "signmap-corpus/1"
HALVES = ("tuning", "check")
# What a resumed run must share with the one it continues, or its records would mix two setups.
RUN_IDENTITY = ("corpus", "calibrate_only", "true_camera", "config_overrides", "replay_of",
                "true_camera_focal_scale", "stored_camera", "as_video", "antenna_undeclared",
                "gps_jump")
# What a run written before a field of RUN_IDENTITY existed had instead.
IDENTITY_BEFORE = {"true_camera_focal_scale": 1.0, "stored_camera": False, "as_video": False,
                   "antenna_undeclared": False, "gps_jump": False}
# A hand-set dash cam clock is seconds off GPS time; whole seconds, because an MP4's creation_time
# holds no fraction (a fractional error would be written truncated, and the truth be wrong).
CLOCK_ERROR_MAX_S = 5
# The "video" stage report's summary (app.pipeline.bundle.video.read._offset).
CLOCK_ESTIMATED = re.compile(r"clock offset estimated: the camera's clock is ([-+]?[\d.]+) s "
                             r"± ([\d.]+) s")
CLOCK_NOT_ESTIMATED = re.compile(r"clock offset not estimated \((.*)\); .* stands")


class CorpusPaths(NamedTuple):
    markdown: Path
    json: Path
    png: Path
    jsonl: Path


def log(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


def load_corpus(corpus_dir: Path) -> dict:
    index = json.loads((Path(corpus_dir) / "corpus.json").read_text())
    if index.get("format") != CORPUS_FORMAT:
        raise ValueError(f"{corpus_dir}/corpus.json has format {index.get('format')!r}, "
                         f"expected {CORPUS_FORMAT!r}")
    return index


def select_journeys(index: dict, *, half: str | None = None, names: list[str] | None = None,
                    limit: int | None = None) -> list[dict]:
    """The corpus entries to run, in corpus order: ``limit`` applies last, so a resumed run with
    the same arguments continues the same selection."""
    journeys = index["journeys"]
    if half is not None:
        if half not in HALVES:
            raise ValueError(f"half must be one of {HALVES}, not {half!r}")
        journeys = [j for j in journeys if j.get("half") == half]
    if names:
        unknown = set(names) - {j["name"] for j in index["journeys"]}
        if unknown:
            raise ValueError(f"not in the corpus: {', '.join(sorted(unknown))}")
        journeys = [j for j in journeys if j["name"] in set(names)]
    return journeys[:limit] if limit is not None else journeys


def pipeline_config(overrides: dict[str, Any]) -> PipelineConfig:
    """The pipeline settings every bench uses (``SIGNMAP_PIPELINE__*``, else the defaults) with
    ``overrides``. Unknown knobs are an error: pydantic would silently ignore a misspelt one."""
    from app.settings import Settings

    unknown = set(overrides) - set(PipelineConfig.model_fields)
    if unknown:
        raise ValueError(f"unknown pipeline knob(s): {', '.join(sorted(unknown))}")
    return PipelineConfig(**{**Settings().pipeline.model_dump(), **overrides})


def camera_errors(est: dict[str, float], true: dict[str, float]) -> dict[str, float | None]:
    """fx, fy, k1, k2 in % of the true value (None when the true value is 0), k1, k2 also
    absolute, cx, cy in pixels: a principal point is judged against the pixel grid, not its own
    size; ``distortion_px`` and ``projection_px`` (``metrics.distortion_error_px``,
    ``metrics.projection_error_px``) when ``true`` has the image size."""
    out: dict[str, float | None] = {}
    for k in ("fx", "fy", "k1", "k2"):
        out[f"{k}_pct"] = 100.0 * (est[k] - true[k]) / abs(true[k]) if true[k] else None
    for k in ("k1", "k2"):
        out[f"{k}_abs"] = est[k] - true[k]
    for k in ("cx", "cy"):
        out[f"{k}_px"] = est[k] - true[k]
    camera = true_camera(true)
    if camera is not None:
        out["distortion_px"] = distortion_error_px(est, camera)
        out["projection_px"] = projection_error_px(est, camera)
    return out


def calibration_record(result: JourneyResult, true_camera: dict) -> dict:
    cal = result.calibration
    return {**calibration_summary(cal, lambda p: camera_errors(p, true_camera),
                                  camera_key="camera", errors_key="errors"),
            "evidence": cal.evidence,
            "n_images": cal.n_images, "n_registered": cal.n_registered,
            "rotation_deg": float(cal.rotation_deg), "windows": [list(w) for w in cal.windows],
            "focal_std_rel": float(cal.focal_std_rel),
            "intrinsics_std": [float(v) for v in cal.intrinsics_std]}


def bundle_digest(bundle: Path) -> str | None:
    """A fingerprint of a bundle's contents: its members' names, sizes and CRC-32s (the zip's own
    bytes carry write times); None for an unreadable bundle, whose run then fails with the
    pipeline's own reason. Renders of one seed on two machines may differ in a few pixels
    (c0053's calibration moved between two machines' runs of one commit); equal
    digests rule that out before a difference is blamed on the code."""
    try:
        with zipfile.ZipFile(bundle) as z:
            lines = sorted(f"{i.filename}:{i.file_size}:{i.CRC:08x}" for i in z.infolist())
    except (OSError, zipfile.BadZipFile):
        return None
    return hashlib.sha256("\n".join(lines).encode()).hexdigest()[:16]


def stage_reports(out: RunOutput) -> tuple[StageReport, ...]:
    """The stage reports of a run, whether it succeeded or failed."""
    return tuple(out.result.report) if out.result is not None else out.failure_report


def journey_record(entry: dict, out: RunOutput, truth: dict, *, calibrate_only: bool,
                   digest: str | None = None) -> dict:
    """The JSON record of one journey's run; ``digest``: its bundle's ``bundle_digest``."""
    record = {"kind": "journey", "name": entry["name"], "half": entry.get("half"),
              "seed": entry.get("seed"), "params": entry.get("params", {}),
              "bundle_digest": digest,
              "status": "ok" if out.result is not None else "failed", "error": out.error,
              "n_frames": out.n_frames, "wall_s": round(out.wall_s, 2),
              "timings_s": out.timings_s, "calib_s": out.timings_s.get("calibrate"),
              "calibration": None,
              # One line per candidate tried (its registration, turn and the GPS's, the verdict):
              # what a knob that only refuses candidates would change can be read off it.
              "calib_trials": next((list(r.details) for r in stage_reports(out)
                                    if r.stage == "calibrate"), [])}
    if out.result is None:
        return record
    record["calibration"] = calibration_record(out.result, truth["camera"])
    if not calibrate_only and truth.get("signs"):
        ev = evaluate_result(out.result, truth)
        mappable = mappable_ids(truth, RECALL_MIN_FRAMES)
        found = {e["truth_id"] for e in ev["sign_errors"].values()}
        record["signs"] = {**ev["signs"], "n_truth": len(truth["signs"]),
                           "n_mappable": len(mappable),
                           "n_mappable_found": len(found & set(mappable)),
                           "n_rejected": len(ev["rejected"])}
        record["ate"] = ev["ate"]
        record["sign_errors"] = ev["sign_errors"]
        record["unmatched_signs"] = ev["unmatched_signs"]
        became = track_of_sign(truth, out.detections)
        placed = {e["truth_id"]: tid for tid, e in ev["sign_errors"].items()}
        unmatched = {u["track_id"]: u for u in ev["unmatched_signs"]}
        record["missed_mappable"] = {i: _why_not(i, truth, ev["rejected"], became.get(i),
                                                 placed, unmatched)
                                     for i in mappable if i not in found}
        record["rejected"] = ev["rejected"]
        record["broken_windows"] = broken_record(out.result)
    return record


def track_of_sign(truth: dict, detections) -> dict[str, str]:
    """Per true sign id, the track its detections became in the pipeline: the track holding most
    of its true boxes (same frame, IoU >= 0.5), where the bundle gave no track ids; ``detections``
    as in ``RunOutput.detections``."""
    by_frame: dict[str, list[tuple[str, np.ndarray]]] = {}
    for frame_id, track_id, *box in detections:
        by_frame.setdefault(frame_id, []).append((track_id, np.asarray(box, float)))
    out = {}
    for sign in truth["signs"]:
        votes: dict[str, int] = {}
        for ob in sign.get("observations", []):
            box_true = ob.get("box_true")
            if box_true is None:
                continue
            for track_id, box in by_frame.get(ob["frame"], []):
                if box_iou(box[None], np.asarray(box_true, float)[None])[0, 0] >= 0.5:
                    votes[track_id] = votes.get(track_id, 0) + 1
        if votes:
            out[truth_id(sign)] = max(votes, key=votes.get)
    return out


def _why_not(sign_id: str, truth: dict, rejected: dict[str, str], became: str | None = None,
             placed: dict[str, str] | None = None, unmatched: dict[str, dict] | None = None) -> str:
    """Why a mappable true sign was not placed: the pipeline's reason when its track (its own id,
    or ``became``, the track its detections formed) was rejected; or that track's fate."""
    track = next((str(s.get("track_id", "")) for s in truth["signs"] if truth_id(s) == sign_id),
                 "") or became or ""
    if not track:
        return "not placed: none of its detections is in a track"
    if track in rejected:
        return rejected[track]
    if unmatched and track in unmatched:
        u = unmatched[track]
        return (f"placed as {track} {u['nearest_true_m']:.1f} m from the nearest true sign "
                f"(counted {u['kind']})")
    if placed and track in placed.values():
        other = next(t for t, tid in placed.items() if tid == track)
        return f"its track {track} was placed and matched to {other}"
    return f"not placed, no reason given (track {track})"


def clock_error_of(name: str) -> int:
    """The camera clock error (s) a journey gets as a video: a whole number in
    [-CLOCK_ERROR_MAX_S, CLOCK_ERROR_MAX_S], never 0, drawn from its name so that every run, resume
    and machine gives a journey the same one (Python's own ``hash`` is salted per process)."""
    n = CLOCK_ERROR_MAX_S
    k = int(hashlib.sha256(name.encode()).hexdigest(), 16) % (2 * n)
    return k - n if k < n else k - n + 1


class VideoInput(NamedTuple):
    """A journey's frames bundle as a dash cam's video bundle; ``bundle`` None when the conversion
    failed (``error`` says why)."""

    bundle: Path | None
    clock_error_s: int
    convert_s: float
    error: str | None


def video_input(name: str, frames_zip: Path, out_dir: Path) -> VideoInput:
    """``frames_zip`` as ``out_dir/video.zip``: H.264 MP4, its GPS fixes as given in NMEA and an
    undeclared clock error (``clock_error_of``); detections kept, since a dash cam's detector
    sends them too and the video reader keeps the frames they are on."""
    from app.synth.video.bundle import video_bundle

    clock_error_s = clock_error_of(name)
    t0 = time.perf_counter()
    try:
        bundle: Path | None = video_bundle(frames_zip, out_dir / "video.zip", gps_format="nmea",
                                           gps_rate_hz=None, clock_error_s=float(clock_error_s))
        error = None
    except Exception as exc:  # noqa: BLE001 - e.g. no H.264 encoder: that journey's record says so
        bundle, error = None, f"video conversion: {type(exc).__name__}: {exc}"
    return VideoInput(bundle, clock_error_s, round(time.perf_counter() - t0, 2), error)


def video_clock(reports: tuple[StageReport, ...]) -> dict[str, Any]:
    """The clock error the "video" stage estimated, its sigma, and why not when it did not (the
    video never read: the run failed before, its ``error`` says how)."""
    video = next((r for r in reports if r.stage == "video"), None)
    if video is None:
        return {"clock_error_est_s": None, "clock_error_sigma_s": None,
                "clock_offset_reason": "no video report (the run failed before reading it)"}
    if found := CLOCK_ESTIMATED.search(video.summary):
        return {"clock_error_est_s": float(found.group(1)),
                "clock_error_sigma_s": float(found.group(2)), "clock_offset_reason": None}
    refused = CLOCK_NOT_ESTIMATED.search(video.summary)
    return {"clock_error_est_s": None, "clock_error_sigma_s": None,
            "clock_offset_reason": refused.group(1) if refused else video.summary}


def video_fields(video: VideoInput, out: RunOutput) -> dict[str, Any]:
    """What a video run adds to a journey's record; ``video_convert_s`` is kept out of
    ``wall_s`` and ``timings_s`` so that they compare with a frames run's."""
    return {"clock_error_s": video.clock_error_s, "video_convert_s": video.convert_s,
            **video_clock(stage_reports(out))}


def without_antenna_offset(bundle: Path, out: Path) -> Path:
    """``bundle`` copied to ``out`` with its manifest's ``gps_antenna_offset_m`` left out, as a
    fleet that never measured its antennas would upload it."""
    with zipfile.ZipFile(bundle) as src, zipfile.ZipFile(out, "w") as dst:
        for info in src.infolist():
            data = src.read(info)
            if info.filename == "manifest.json":
                manifest = json.loads(data)
                manifest.pop("gps_antenna_offset_m", None)
                data = json.dumps(manifest).encode()
            dst.writestr(info, data)
    return out


def run_journey(corpus_dir: Path, entry: dict, config: PipelineConfig,
                calibrate_only: bool, true_camera: bool = False, *,
                keep_dir: Path | None = None, replay_dir: Path | None = None,
                focal_scale: float = 1.0, stored_camera: bool = False,
                as_video: bool = False, antenna_undeclared: bool = False,
                gps_jump: bool = False, camera: CameraModel | None = None) -> dict:
    """Run the pipeline on one corpus journey in a fresh process; a crash is a failed record.
    ``true_camera`` hands the pipeline the journey's true camera instead of self-calibrating, so
    that sign placement is measured on every journey, those without turns included.
    ``keep_dir``: keep its reconstruction there; ``replay_dir``: georeference the one kept there
    instead of running the pipeline (``bench.corpus.replay``). ``focal_scale``: the true camera's fx
    and fy are handed over times this (what a calibration that many per cent off does to the
    later stages). ``stored_camera``: the true camera (times ``focal_scale``) is handed over as
    the camera's stored calibration, as the service does, and the journey still calibrates itself.
    ``camera``: handed over in place of the true one (with ``true_camera`` or ``stored_camera``).
    ``as_video``: run it as a dash cam's video bundle (``video_input``), made in the journey's
    temporary directory; ``bundle_digest`` stays the frames bundle's, the rendering both share.
    ``antenna_undeclared``: its manifest's antenna offset left out (``without_antenna_offset``).
    ``gps_jump``: a run of its fixes moved metres off (``broken.with_gps_jump``)."""
    jdir = Path(corpus_dir) / entry.get("dir", entry["name"])
    truth = json.loads((jdir / "truth.json").read_text())
    digest = bundle_digest(jdir / "bundle.zip")
    known = None
    if camera is not None:
        known = camera
    elif true_camera or stored_camera:
        cam = truth["camera"]
        known = CameraModel.from_params(cam["width"], cam["height"],
                                        {**cam, "fx": cam["fx"] * focal_scale,
                                         "fy": cam["fy"] * focal_scale})
    if true_camera:
        config = config.model_copy(update={"reuse_known_calibration": True})
    if replay_dir is not None:
        out = _replayed(entry["name"], replay_dir, config)
        return (journey_record(entry, out, truth, calibrate_only=calibrate_only, digest=digest)
                | antenna.estimate_fields(stage_reports(out)))
    with tempfile.TemporaryDirectory(prefix=f"bench-corpus-{entry['name']}-") as tmp:
        frames = (without_antenna_offset(jdir / "bundle.zip", Path(tmp) / "bundle.zip")
                  if antenna_undeclared else jdir / "bundle.zip")
        jump = (with_gps_jump(frames, Path(tmp) / "jumped.zip", gps_jump_of(entry["name"]))
                if gps_jump else None)
        frames = frames if jump is None else Path(tmp) / "jumped.zip"
        video = video_input(entry["name"], frames, Path(tmp)) if as_video else None
        bundle = frames if video is None else video.bundle
        if video is not None and bundle is None:
            out = RunOutput(entry["name"], None, video.error, 0, 0.0, {}, {})
        else:
            task = RunTask(entry["name"], bundle, Path(tmp), config.model_dump(),
                           known_camera=known, calibrate_only=calibrate_only,
                           keep_reconstruction=(None if keep_dir is None
                                                else replay.path_for(keep_dir, entry["name"])))
            out = _run(task)
    record = journey_record(entry, out, truth, calibrate_only=calibrate_only, digest=digest)
    record |= antenna.estimate_fields(stage_reports(out))
    if jump is not None:
        record["gps_jump"] = jump
    return record if video is None else {**record, **video_fields(video, out)}


def _run(task: RunTask) -> RunOutput:
    t0 = time.perf_counter()
    try:
        return run_isolated(task)
    except Exception as exc:  # noqa: BLE001 - e.g. an unreadable bundle: raised in the child
        return RunOutput(task.label, None, f"{type(exc).__name__}: {exc}", 0,
                         time.perf_counter() - t0, {}, {})


def _replayed(name: str, replay_dir: Path, config: PipelineConfig) -> RunOutput:
    """The journey's kept reconstruction georeferenced with ``config``, as a run's output (in
    this process: no COLMAP runs). A journey with nothing kept (its run's process died) is a
    failed record, as it was in the kept run."""
    path = replay.path_for(replay_dir, name)
    if not path.is_file():
        return RunOutput(name, None, f"no reconstruction kept in {replay_dir} (the kept run's "
                         "process died?)", 0, 0.0, {}, {})
    journey, result, error, seconds = replay.replay(path, config)
    timings = {"read": 0.0, **(result.timings_s if result else {})}
    return RunOutput(name, result, error, len(journey.frames), seconds, timings, {},
                     detections=detections_of(journey))


def _clock_note(record: dict) -> str:
    if "clock_error_s" not in record:
        return ""
    est = record["clock_error_est_s"]
    return (f"; camera clock {record['clock_error_s']:+d} s, "
            + ("not estimated" if est is None else f"estimated {est:+.2f} s"))


def read_jsonl(path: Path) -> tuple[dict | None, list[dict]]:
    """(meta line, journey records) of a run's JSONL; a line cut short by a kill is skipped."""
    meta, records = None, []
    for line in path.read_text().splitlines():
        try:
            item = json.loads(line)
        except json.JSONDecodeError:
            continue
        if item.get("kind") == "meta":
            meta = item
        elif item.get("kind") == "journey":
            records.append(item)
    return meta, records


def read_records(paths: list[Path]) -> list[dict]:
    """The journey records of several runs' JSONL files, pooled (e.g. two corpora of consecutive
    seeds)."""
    return [record for path in paths for record in read_jsonl(path)[1]]


def _append(path: Path, item: dict) -> None:
    with path.open("a") as f:
        f.write(json.dumps(finite(item), allow_nan=False) + "\n")


def _jsonl_path(out_dir: Path, suffix: str, resume: bool) -> Path:
    """A resumed run continues the latest JSONL of the same tag (it may have started on an
    earlier day); a new run gets today's."""
    if resume:
        existing = sorted(out_dir.glob(f"*-corpus{suffix}.jsonl"))
        if existing:
            return existing[-1]
    return out_dir / f"{dt.date.today().isoformat()}-corpus{suffix}.jsonl"


def run_corpus(corpus_dir: Path, out_dir: Path, *, half: str | None = None,
               limit: int | None = None, names: list[str] | None = None,
               calibrate_only: bool = False, true_camera: bool = False,
               config_overrides: dict[str, Any] | None = None,
               tag: str = "", resume: bool = False, keep_dir: Path | None = None,
               replay_dir: Path | None = None, focal_scale: float = 1.0,
               stored_camera: bool = False, as_video: bool = False,
               antenna_undeclared: bool = False, gps_jump: bool = False) -> CorpusPaths:
    """Run the selected journeys of the corpus in ``corpus_dir``; write ``<date>-corpus<tag>``
    .jsonl (records), .md, .json and .png into ``out_dir``. ``keep_dir`` / ``replay_dir``: keep
    each journey's reconstruction there, or only georeference those kept there
    (``bench.corpus.replay``); a replayed record's ``timings_s`` up to ego-motion are the kept run's.
    ``as_video``: each journey as a dash cam's video bundle (``run_journey``)."""
    corpus_dir, out_dir = Path(corpus_dir), Path(out_dir)
    if keep_dir is not None and replay_dir is not None:
        raise ValueError("a replay keeps no reconstruction: give --keep-reconstructions or "
                         "--replay, not both")
    if as_video and replay_dir is not None:
        raise ValueError("a replay reads no bundle: give --as-video or --replay, not both")
    if replay_dir is not None and not Path(replay_dir).is_dir():
        raise ValueError(f"--replay {replay_dir}: no such directory")
    overrides = dict(config_overrides or {})
    config = pipeline_config(overrides)
    index = load_corpus(corpus_dir)
    selection = select_journeys(index, half=half, names=names, limit=limit)
    out_dir.mkdir(parents=True, exist_ok=True)
    suffix = f"-{tag.lstrip('-')}" if tag else ""
    jsonl = _jsonl_path(out_dir, suffix, resume)
    meta = {"kind": "meta", **run_meta(False, config), "corpus": str(corpus_dir.resolve()),
            "corpus_seed": index.get("seed"), "corpus_n": index.get("n"),
            "generator_version": index.get("generator_version"), "calibrate_only": calibrate_only,
            "true_camera": true_camera, "true_camera_focal_scale": focal_scale,
            "stored_camera": stored_camera, "as_video": as_video,
            "antenna_undeclared": antenna_undeclared, "gps_jump": gps_jump,
            "config_overrides": overrides, "tag": tag,
            "replay_of": None if replay_dir is None else str(Path(replay_dir).resolve())}
    meta.pop("quick", None)
    old_meta, records = read_jsonl(jsonl) if resume and jsonl.exists() else (None, [])
    if old_meta is not None:
        differs = [k for k in RUN_IDENTITY
                   if old_meta.get(k, IDENTITY_BEFORE.get(k)) != finite(meta[k])]
        if differs:
            raise ValueError(f"{jsonl} was run with other {', '.join(differs)}: use another --tag")
        meta = old_meta
    else:
        jsonl.write_text("")
        _append(jsonl, meta)
    done = {r["name"] for r in records}
    t0 = time.perf_counter()
    paths = CorpusPaths(jsonl.with_suffix(".md"), jsonl.with_suffix(".json"),
                        jsonl.with_suffix(".png"), jsonl)
    todo = [e for e in selection if e["name"] not in done]
    log(f"corpus {corpus_dir}: {len(selection)} journeys selected, {len(selection) - len(todo)} "
        f"already in {jsonl.name}")
    for i, entry in enumerate(todo, start=1):
        log(f"[{i}/{len(todo)}] {entry['name']} ({entry.get('half')}): running")
        record = run_journey(corpus_dir, entry, config, calibrate_only, true_camera,
                             keep_dir=keep_dir, replay_dir=replay_dir, focal_scale=focal_scale,
                             stored_camera=stored_camera, as_video=as_video,
                             antenna_undeclared=antenna_undeclared, gps_jump=gps_jump)
        _append(jsonl, record)
        records.append(record)
        log(f"[{i}/{len(todo)}] {entry['name']}: {record['status']} in {record['wall_s']:.0f} s"
            + (f" ({record['error']})" if record["error"] else "") + _clock_note(record))
        # The report is rewritten after every journey, like the suite's: it is cheap.
        corpus_report.write_report(meta, records, paths.markdown, paths.json, paths.png,
                                   time.perf_counter() - t0)
    corpus_report.write_report(meta, records, paths.markdown, paths.json, paths.png,
                               time.perf_counter() - t0)
    return paths
