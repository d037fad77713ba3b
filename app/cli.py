"""``signmap`` command line: the pipeline locally, the synthetic generator, the service and the
benchmarks. The subcommands run in ``app.commands``: ``signmap process`` in
``app.commands.process`` (its exit codes), ``signmap synth`` in ``app.commands.synth``. Service
subcommands live in ``app.service.commands`` so the pipeline CLI does not import the service
stack."""

from __future__ import annotations

import argparse
import sys

from app.commands.process import EXIT_CODES_HELP, EXIT_USAGE

DESCRIPTION = ("Signmap: 3D positions of traffic signs from journeys filmed by cameras nobody "
               "calibrated, with GPS. Process a journey on this machine, render synthetic "
               "journeys to try it on, run the HTTP service and its workers, and run the "
               "benchmarks. `signmap COMMAND --help` says more about each command.")


class HelpFormatter(argparse.HelpFormatter):
    """argparse's, except that text with line breaks of its own (the exit-status table) is kept
    as written instead of being refilled."""

    def _fill_text(self, text: str, width: int, indent: str) -> str:
        if "\n" in text:
            return "".join(indent + line for line in text.splitlines(keepends=True))
        return super()._fill_text(text, width, indent)


def show_help(parser: argparse.ArgumentParser):
    """A command function that prints ``parser``'s help (a command given without its subcommand)
    and returns the usage-error exit code."""
    def show(args) -> int:
        parser.print_help()
        return EXIT_USAGE
    return show


def _add_process(sub) -> None:
    p = sub.add_parser(
        "process", help="find the signs of one journey on this machine (no server needed)",
        description="Runs the whole pipeline on one journey bundle: calibrates the camera on the "
        "journey's turns, reconstructs its motion around each sign, aligns it to GPS and "
        "triangulates the signs. Progress goes to stderr; the signs and a report are written "
        "as files.",
        epilog=EXIT_CODES_HELP, formatter_class=HelpFormatter)
    p.add_argument("bundle", help="the journey: a .zip of frames, GPS and sign detections as "
                   "described in docs/journey-format.md")
    p.add_argument("--out", default="signs.geojson",
                   help="where to write the signs as GeoJSON (default: %(default)s)")
    p.add_argument("--report", default=None,
                   help="where to write the JSON report: calibration, timings, what each stage "
                   "tried (and why it failed), uncertainty per sign, rejected tracks and why "
                   "(default: OUT with the suffix .report.json, e.g. signs.report.json)")
    p.add_argument("--calibration", default=None, metavar="CAMERA.json",
                   help="this camera's calibration, a JSON object {fx, fy, cx, cy, k1, k2}; "
                   "needed for a journey without a turn to calibrate on")
    p.add_argument("--workdir", default=None,
                   help="keep the intermediate files (extracted frames, reconstructions) in this "
                   "directory (default: a temporary one, deleted at the end)")
    p.add_argument("--verbose", action="store_true", help="also show COLMAP's own log")


def _add_synth(sub) -> None:
    p = sub.add_parser("synth", help="render a synthetic journey bundle plus its ground truth",
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
    c.add_argument("--n", type=int, required=True, help="number of journeys")
    c.add_argument("--seed", type=int, default=0,
                   help="first journey's seed (journeys seed..seed+n-1; default: %(default)s)")
    c.add_argument("--out", required=True, help="corpus directory (corpus.json, <name>/...)")
    c.add_argument("--workers", type=int, default=1,
                   help="journeys rendered in parallel (default: %(default)s)")
    c.add_argument("--max-frames", type=int, default=None,
                   help="cap on frames per journey (default 300)")


def build_parser() -> argparse.ArgumentParser:
    """The whole ``signmap`` parser (service and bench commands when their modules import)."""
    parser = argparse.ArgumentParser(prog="signmap", description=DESCRIPTION,
                                     epilog=EXIT_CODES_HELP,
                                     formatter_class=HelpFormatter)
    parser.set_defaults(func=show_help(parser))
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
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
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if args.command == "process":
        from app.commands.process import run_process
        return run_process(args)
    if args.command == "synth":
        from app.commands.synth import run_synth
        return run_synth(args)
    return int(args.func(args) or 0)


if __name__ == "__main__":
    sys.exit(main())
