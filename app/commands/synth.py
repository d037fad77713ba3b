"""``signmap synth``: render a synthetic journey bundle and its ground truth; ``signmap synth
corpus``: a varied corpus of them (``app.synth.corpus``)."""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from app.synth.journey import SynthConfig

COMMANDS = {"synth": "render a synthetic journey bundle plus its ground truth"}


def add_parsers(sub) -> None:
    """``signmap synth`` and ``signmap synth corpus``."""
    p = sub.add_parser("synth", help=COMMANDS["synth"],
                       description="Renders a synthetic journey (frames, GPS, detections) into "
                       "OUT/bundle.zip and the true sign positions and camera into "
                       "OUT/truth.json. `signmap synth corpus` renders a varied set of them.")
    p.add_argument("--seed", type=int, default=0,
                   help="seed of the journey's noise (GPS, camera shake, detection boxes): the "
                   "same seed gives the same journey (default: %(default)s)")
    p.add_argument("--frames", type=int, default=120,
                   help="number of frames to render (default: %(default)s)")
    p.add_argument("--turns", type=int, default=1,
                   help="number of ~90 degree turns; 0 = a straight road (default: %(default)s)")
    p.add_argument("--out", default=None,
                   help="output directory for bundle.zip and truth.json (required)")
    p.add_argument("--world-seed", type=int, default=None,
                   help="seed of the road and sign layout (default: the value of --seed)")
    p.add_argument("--low-texture", action="store_true", help="weak, low-contrast textures")
    p.add_argument("--loop", action="store_true", help="a closed loop back to the start (4 turns)")
    p.add_argument("--lateral-offset", type=float, default=0.0, metavar="METRES",
                   help="drive this many metres right of the road centreline (default: 0)")
    p.add_argument("--image-format", choices=["png", "jpg"], default=None,
                   help="frame image format (default: png; jpg with --gps-format exif)")
    p.add_argument("--gps-format", choices=["csv", "gpx", "exif"], default=None,
                   help="how the bundle carries GPS: gps.csv, gps.gpx or EXIF tags in the frames "
                   "(default: csv)")
    synth_sub = p.add_subparsers(dest="synth_command", metavar="{corpus}")
    c = synth_sub.add_parser("corpus", help="a varied corpus of journeys (cameras, lenses, turns, "
                             "speeds, scenes, GPS receivers, detectors), each with its truth")
    size = c.add_mutually_exclusive_group(required=True)
    size.add_argument("--n", type=int, help="number of journeys")
    size.add_argument("--cameras", type=int,
                      help="a fleet instead: this many cameras, each driving 3-8 journeys of its "
                      "own (one camera_id, one lens); --seed is the first camera's")
    c.add_argument("--seed", type=int, default=0,
                   help="first journey's seed (journeys seed..seed+n-1; default: %(default)s)")
    c.add_argument("--out", required=True, help="corpus directory (corpus.json, <name>/...)")
    c.add_argument("--workers", type=int, default=1,
                   help="journeys rendered in parallel (default: %(default)s)")
    c.add_argument("--max-frames", type=int, default=None,
                   help="cap on frames per journey (default 300)")
    c.add_argument("--frame-spacing-m", type=float, nargs=2, metavar=("LO", "HI"), default=None,
                   help="with --n: only journeys whose consecutive frames lie LO-HI m apart at "
                   "the cruise speed, --n / 2 per half")
    c.add_argument("--antenna-offsets", action="store_true",
                   help="with --n: each journey's GPS antenna up to 1.5 m from its camera (the "
                   "fixes are the antenna's), the offset declared in its manifest")
    p.set_defaults(func=run_synth)


def config_from_args(args) -> SynthConfig:
    """A SynthConfig from parsed ``signmap synth`` arguments (options not given keep defaults)."""
    from app.synth.journey import SynthConfig

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
    from app.synth.corpus import write_corpus, write_fleet
    from app.synth.draw import MAX_FRAMES

    t0 = time.perf_counter()
    write = write_corpus if args.n is not None else write_fleet
    options = ({"frame_spacing_m": tuple(args.frame_spacing_m)}
               if args.n is not None and args.frame_spacing_m else {})
    if args.antenna_offsets:
        if args.n is None:
            print("signmap synth corpus: --antenna-offsets goes with --n", file=sys.stderr)
            return 2
        options["antenna_offsets"] = True
    path = write(args.n if args.n is not None else args.cameras, args.seed, Path(args.out),
                 workers=args.workers, max_frames=args.max_frames or MAX_FRAMES, **options)
    n = len(json.loads(path.read_text())["journeys"])
    print(path)
    print(f"{n} journeys in {time.perf_counter() - t0:.1f} s", file=sys.stderr)
    return 0


def run_synth(args) -> int:
    from app.synth.journey import write_bundle

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
