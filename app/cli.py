"""``signmap`` command line: the pipeline locally, the synthetic generator, the service and the
benchmarks. Each group of subcommands adds its own parser from ``app.commands`` (``process``,
``synth``, ``service``; ``bench.cli``); the exit statuses are ``app.commands.usage``'s. The service
and bench groups are imported only here, so the pipeline CLI runs without the service stack."""

from __future__ import annotations

import argparse
import sys

from app.commands import process, synth
from app.commands.usage import EXIT_CODES_HELP, HelpFormatter, show_help

DESCRIPTION = ("Signmap: 3D positions of traffic signs from journeys filmed by cameras nobody "
               "calibrated, with GPS. Process a journey on this machine, render synthetic "
               "journeys to try it on, run the HTTP service and its workers, and run the "
               "benchmarks. `signmap COMMAND --help` says more about each command.")


def build_parser() -> argparse.ArgumentParser:
    """The whole ``signmap`` parser (service and bench commands when their modules import)."""
    parser = argparse.ArgumentParser(prog="signmap", description=DESCRIPTION,
                                     epilog=EXIT_CODES_HELP,
                                     formatter_class=HelpFormatter)
    parser.set_defaults(func=show_help(parser))
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    process.add_parser(sub)
    synth.add_parser(sub)
    try:
        from app.commands import service as service_commands
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
    return int(args.func(args) or 0)


if __name__ == "__main__":
    sys.exit(main())
