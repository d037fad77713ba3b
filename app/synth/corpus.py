"""``signmap synth corpus``: many varied journeys, each in ``<out>/<name>/`` (bundle.zip and
truth.json, whose ``corpus`` entry holds its seed, half and drawn parameters), listed in
``<out>/corpus.json``. Journeys already written by the same generator version with the same
parameters are kept (a cache), so a corpus grows or resumes cheaply."""

from __future__ import annotations

import json
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

from app.synth.bundle import GENERATOR_VERSION
from app.synth.draw import MAX_FRAMES, draw_journey
from app.synth.journey import write_bundle

CORPUS_FORMAT = "signmap-corpus/1"
__all__ = ["CORPUS_FORMAT", "draw_journey", "journey_name", "write_corpus"]


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


def write_journey_dir(seed: int, out: Path, max_frames: int = MAX_FRAMES) -> dict:
    """Draw and (unless cached) render journey ``seed``; returns its corpus.json entry plus
    ``seconds`` and ``cached``."""
    cfg, params = draw_journey(seed, max_frames)
    name = journey_name(seed)
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
    return (f"{e['name']} {e['half']:6s} {p['kind']}/{p['turn_kind']} "
            f"turn {p['max_turn_deg']:.0f}° "
            f"{p['n_frames']} fr @{p['fps']:g} Hz {p['speed_mps']:.1f} m/s "
            f"{p['width']}x{p['height']} hfov {p['hfov_deg']:.0f}° k1 {p['k1']:+.2f} "
            f"{p['scene']} gps {p['gps_rate_hz']:g} Hz {p['gps_white_sigma_m']:.1f} m: {what}")


def write_corpus(n: int, seed: int, out: Path, *, workers: int = 1,
                 max_frames: int = MAX_FRAMES) -> Path:
    """Journeys of seeds ``seed .. seed + n - 1`` into ``out``; returns ``out/corpus.json``."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    seeds = list(range(seed, seed + n))
    entries: dict[int, dict] = {}
    if workers <= 1:
        for s in seeds:
            entries[s] = write_journey_dir(s, out, max_frames)
            print(_log_line(entries[s]), file=sys.stderr, flush=True)
    else:
        with ProcessPoolExecutor(max_workers=workers) as pool:
            futures = {pool.submit(write_journey_dir, s, out, max_frames): s for s in seeds}
            for fut in futures:  # in seed order; each line when its journey is done
                entries[futures[fut]] = fut.result()
                print(_log_line(entries[futures[fut]]), file=sys.stderr, flush=True)
    index = {"format": CORPUS_FORMAT, "seed": seed, "n": n,
             "generator_version": GENERATOR_VERSION, "max_frames": max_frames,
             "journeys": [{k: entries[s][k] for k in ("name", "seed", "half", "dir", "params")}
                          for s in seeds]}
    path = out / "corpus.json"
    path.write_text(json.dumps(index, indent=1))
    return path
