"""``signmap synth``: render a synthetic journey bundle and its ground truth; ``signmap synth
corpus``: a varied corpus of them (``app.synth.corpus``)."""

from __future__ import annotations

import sys
import time
from pathlib import Path

from app.synth.journey import SynthConfig, write_bundle


def config_from_args(args) -> SynthConfig:
    """A SynthConfig from parsed ``signmap synth`` arguments (options not given keep defaults)."""
    opt = {
        "seed": getattr(args, "seed", 0),
        "n_frames": getattr(args, "frames", 120),
        "turns": getattr(args, "turns", 1),
        "world_seed": getattr(args, "world_seed", None),
        "low_texture": getattr(args, "low_texture", False),
        "loop": getattr(args, "loop", False),
        "lateral_offset_m": getattr(args, "lateral_offset", 0.0),
        "image_format": getattr(args, "image_format", None),
        "gps_format": getattr(args, "gps_format", None),
    }
    if opt["world_seed"] is None:
        opt["world_seed"] = opt["seed"]
    return SynthConfig(**{k: v for k, v in opt.items() if v is not None})


def run_corpus(args) -> int:
    from app.synth.corpus import write_corpus
    from app.synth.draw import MAX_FRAMES

    t0 = time.perf_counter()
    path = write_corpus(args.n, args.seed, Path(args.out), workers=args.workers,
                        max_frames=args.max_frames or MAX_FRAMES)
    print(path)
    print(f"{args.n} journeys in {time.perf_counter() - t0:.1f} s", file=sys.stderr)
    return 0


def run_synth(args) -> int:
    if getattr(args, "synth_command", None) == "corpus":
        return run_corpus(args)
    if args.out is None:
        print("signmap synth: the following arguments are required: --out", file=sys.stderr)
        return 2
    cfg = config_from_args(args)
    out = Path(args.out)
    t0 = time.perf_counter()
    try:
        bundle = write_bundle(cfg, out)
    except ValueError as exc:
        print(f"signmap synth: {exc}", file=sys.stderr)
        return 2
    print(f"{bundle}\n{out / 'truth.json'}")
    print(f"{cfg.n_frames} frames in {time.perf_counter() - t0:.1f} s", file=sys.stderr)
    return 0
