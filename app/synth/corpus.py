"""``signmap synth corpus``: many varied journeys, each in ``<out>/<name>/`` (bundle.zip and
truth.json, whose ``corpus`` entry holds its seed, half and drawn parameters), listed in
``<out>/corpus.json``. Journeys already written by the same generator version with the same
parameters are kept (a cache), so a corpus grows or resumes cheaply. ``write_fleet``: the same for
cameras that each drive several journeys (``app.synth.draw.fleet``)."""

from __future__ import annotations

import json
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from functools import partial
from pathlib import Path

from app.synth.bundle import GENERATOR_VERSION
from app.synth.draw import MAX_FRAMES, draw_journey
from app.synth.draw.fleet import draw_fleet_journey, fleet_journey_name, fleet_size
from app.synth.journey import write_bundle

CORPUS_FORMAT = "signmap-corpus/1"
__all__ = ["CORPUS_FORMAT", "draw_journey", "journey_name", "write_corpus", "write_fleet"]


def journey_name(seed: int) -> str:
    return f"c{seed:04d}"


def _jsonable(params: dict) -> dict:
    return json.loads(json.dumps(params))


def _cached(jdir: Path, params: dict) -> bool:
    truth_path = jdir / "truth.json"
    if not truth_path.exists() or not (jdir / "bundle.zip").exists():
        return False
    try:
        truth = json.loads(truth_path.read_text())
    except (OSError, json.JSONDecodeError):
        return False
    return (truth.get("generator_version") == GENERATOR_VERSION
            and truth.get("corpus", {}).get("params") == _jsonable(params))


def write_journey_dir(seed: int, out: Path, max_frames: int = MAX_FRAMES, *,
                      antenna_offset: bool = False) -> dict:
    """Draw and (unless cached) render journey ``seed`` (``draw_journey``); returns its
    corpus.json entry plus ``seconds`` and ``cached``."""
    return _write_drawn(journey_name(seed), seed,
                        *draw_journey(seed, max_frames, antenna_offset=antenna_offset), out)


def write_fleet_journey(key: tuple[int, int], out: Path, max_frames: int = MAX_FRAMES) -> dict:
    """``write_journey_dir`` for journey ``key[1]`` of fleet camera ``key[0]``."""
    camera_seed, k = key
    cfg, params = draw_fleet_journey(camera_seed, k, max_frames)
    return _write_drawn(fleet_journey_name(camera_seed, k), cfg.seed, cfg, params, out)


def _write_drawn(name: str, seed: int, cfg, params: dict, out: Path) -> dict:
    jdir = Path(out) / name
    entry = {"name": name, "seed": seed, "half": params["half"], "dir": name,
             "params": _jsonable(params)}
    t0 = time.perf_counter()
    cached = _cached(jdir, params)
    if not cached:
        write_bundle(cfg, jdir)
        truth_path = jdir / "truth.json"
        truth = json.loads(truth_path.read_text())
        truth["corpus"] = {"seed": seed, "half": params["half"], "params": entry["params"]}
        tmp = truth_path.with_suffix(".json.part")
        tmp.write_text(json.dumps(truth, indent=1))
        tmp.replace(truth_path)  # written last: its presence marks a finished journey
    return {**entry, "seconds": time.perf_counter() - t0, "cached": cached}


def _log_line(e: dict) -> str:
    p = e["params"]
    what = "cached" if e["cached"] else f"{e['seconds']:.1f} s"
    rate = f"{p['gps_rate_hz']:g} Hz" if p["gps_rate_hz"] else "each frame"  # short journeys
    return (f"{e['name']} {e['half']:6s} {p['kind']}/{p['turn_kind']} "
            f"turn {p['max_turn_deg']:.0f}° "
            f"{p['n_frames']} fr @{p['fps']:g} Hz {p['speed_mps']:.1f} m/s "
            f"{p['width']}x{p['height']} hfov {p['hfov_deg']:.0f}° k1 {p['k1']:+.2f} "
            f"{p['scene']} gps {rate} {p['gps_white_sigma_m']:.1f} m{_antenna(p)}: {what}")


def _antenna(params: dict) -> str:
    offset = params.get("gps_antenna_offset_m")
    return "" if offset is None else " antenna {:+.2f} {:+.2f} {:+.2f} m".format(*offset)


def write_corpus(n: int, seed: int, out: Path, *, workers: int = 1,
                 max_frames: int = MAX_FRAMES,
                 frame_spacing_m: tuple[float, float] | None = None,
                 antenna_offsets: bool = False) -> Path:
    """Journeys of seeds ``seed .. seed + n - 1`` into ``out`` (with ``frame_spacing_m``, those of
    ``spacing_seeds``; with ``antenna_offsets``, each GPS antenna away from its camera and the
    offset declared); returns ``out/corpus.json``."""
    seeds = (list(range(seed, seed + n)) if frame_spacing_m is None
             else spacing_seeds(n, seed, max_frames, frame_spacing_m))
    write = partial(write_journey_dir, antenna_offset=antenna_offsets)
    return _write_index(seeds, write, out, workers, max_frames,
                        {"seed": seed, "n": n}
                        | ({"frame_spacing_m": list(frame_spacing_m)} if frame_spacing_m else {})
                        | ({"antenna_offsets": True} if antenna_offsets else {}))


def spacing_seeds(n: int, seed: int, max_frames: int, frame_spacing_m: tuple[float, float]
                  ) -> list[int]:
    """The first ``n // 2`` tuning and ``n // 2`` check seeds from ``seed`` on whose consecutive
    frames lie more than lo and at most hi metres apart at the cruise speed (``frame_spacing_m``):
    a corpus of the journeys one front end or another serves (issue 68's)."""
    lo, hi = frame_spacing_m
    picked: dict[str, list[int]] = {"tuning": [], "check": []}
    candidate = seed
    while min(map(len, picked.values())) < n // 2:
        _, params = draw_journey(candidate, max_frames)
        half = picked[params["half"]]
        if lo < params["speed_mps"] / params["fps"] <= hi and len(half) < n // 2:
            half.append(candidate)
        candidate += 1
    return picked["tuning"] + picked["check"]


def write_fleet(cameras: int, seed: int, out: Path, *, workers: int = 1,
                max_frames: int = MAX_FRAMES) -> Path:
    """The journeys of fleet cameras ``seed .. seed + cameras - 1`` (``fleet_size`` each) into
    ``out``; returns ``out/corpus.json``, whose entries' ``params`` carry ``camera_id``."""
    keys = [(c, k) for c in range(seed, seed + cameras) for k in range(fleet_size(c))]
    return _write_index(keys, write_fleet_journey, out, workers, max_frames,
                        {"seed": seed, "n": len(keys), "cameras": cameras})


def _write_index(keys: list, write, out: Path, workers: int, max_frames: int,
                 header: dict) -> Path:
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    entries: dict = {}
    if workers <= 1:
        for key in keys:
            entries[key] = write(key, out, max_frames)
            print(_log_line(entries[key]), file=sys.stderr, flush=True)
    else:
        with ProcessPoolExecutor(max_workers=workers) as pool:
            futures = {pool.submit(write, key, out, max_frames): key for key in keys}
            for fut in futures:  # in key order; each line when its journey is done
                entries[futures[fut]] = fut.result()
                print(_log_line(entries[futures[fut]]), file=sys.stderr, flush=True)
    index = {"format": CORPUS_FORMAT, **header,
             "generator_version": GENERATOR_VERSION, "max_frames": max_frames,
             "journeys": [{k: entries[key][k] for k in ("name", "seed", "half", "dir", "params")}
                          for key in keys]}
    path = out / "corpus.json"
    path.write_text(json.dumps(index, indent=1))
    return path
