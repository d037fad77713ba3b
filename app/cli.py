"""``signmap`` command line: the pipeline locally, the synthetic generator, the service and the
benchmarks. Service subcommands live in ``app.service.commands`` so the pipeline CLI does not import
the service stack."""

from __future__ import annotations

import argparse
import sys


def _add_process(sub) -> None:
    p = sub.add_parser("process", help="run the pipeline on one journey bundle, locally")
    p.add_argument("bundle", help="journey .zip (the wire contract)")
    p.add_argument("--out", default="signs.geojson", help="GeoJSON of the triangulated signs")
    p.add_argument("--report", default=None, help="JSON report (default: <out>.report.json)")
    p.add_argument("--calibration", default=None,
                   help="JSON {fx,fy,cx,cy,k1,k2} of this camera, used when the journey has no turn")
    p.add_argument("--workdir", default=None, help="keep intermediate files here")
    p.add_argument("--verbose", action="store_true", help="show COLMAP's own log")


def _add_synth(sub) -> None:
    p = sub.add_parser("synth", help="render a synthetic journey bundle plus its ground truth")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--frames", type=int, default=120)
    p.add_argument("--turns", type=int, default=1, help="number of ~90 degree turns (0 = straight)")
    p.add_argument("--out", default=None, help="output directory (bundle.zip, truth.json)")
    p.add_argument("--world-seed", type=int, default=None, help="world layout seed (default: --seed)")
    p.add_argument("--low-texture", action="store_true", help="weak, low-contrast textures")
    p.add_argument("--loop", action="store_true", help="a closed loop back to the start (4 turns)")
    p.add_argument("--lateral-offset", type=float, default=0.0,
                   help="drive this many metres right of the road centreline")
    p.add_argument("--image-format", choices=["png", "jpg"], default=None)
    p.add_argument("--gps-format", choices=["csv", "gpx", "exif"], default=None)
    synth_sub = p.add_subparsers(dest="synth_command", metavar="{corpus}")
    c = synth_sub.add_parser("corpus", help="a varied corpus of journeys (cameras, lenses, turns, "
                             "speeds, scenes, GPS receivers, detectors), each with its truth")
    c.add_argument("--n", type=int, required=True, help="number of journeys")
    c.add_argument("--seed", type=int, default=0,
                   help="first journey's seed (journeys seed..seed+n-1)")
    c.add_argument("--out", required=True, help="corpus directory (corpus.json, <name>/...)")
    c.add_argument("--workers", type=int, default=1, help="journeys rendered in parallel")
    c.add_argument("--max-frames", type=int, default=None,
                   help="cap on frames per journey (default 300)")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="signmap", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    _add_process(sub)
    _add_synth(sub)
    try:
        from app.service import commands as service_commands
    except ImportError:  # the service extras are not installed: pipeline-only CLI
        service_commands = None
    if service_commands is not None:
        service_commands.add_parsers(sub)
    try:
        from bench import cli as bench_cli
    except ImportError:
        bench_cli = None
    if bench_cli is not None:
        bench_cli.add_parsers(sub)
    args = parser.parse_args(argv)
    if args.command == "process":
        from app.pipeline.process_cli import run_process
        return run_process(args)
    if args.command == "synth":
        from app.synth.cli import run_synth
        return run_synth(args)
    return int(args.func(args) or 0)


if __name__ == "__main__":
    sys.exit(main())
