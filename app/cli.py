"""``signmap`` command line: the pipeline locally, the synthetic generator, the service and the
benchmarks. Each group of subcommands adds its own parsers from ``app.commands`` (``process``,
``synth``, ``service``, ``cameras``; ``bench.cli``); the exit statuses are ``app.commands.usage``'s.

Only the group of the command being run builds its parsers: building them imports what their
options need (the service's roles, the benches' stack), and ``signmap --help`` should not wait
for the pipeline, the database or the web stack to load. The other groups are listed by name and
help."""

from __future__ import annotations

import argparse
import sys

from app.commands import cameras, process, service, synth
from app.commands.usage import EXIT_CODES_HELP, HelpFormatter, show_help
from bench import cli as bench_cli

DESCRIPTION = ("Signmap: 3D positions of traffic signs from journeys filmed by cameras nobody "
               "calibrated, with GPS. Process a journey on this machine, render synthetic "
               "journeys to try it on, run the HTTP service and its workers, and run the "
               "benchmarks. `signmap COMMAND --help` says more about each command.")

# Each module's COMMANDS: {command: one-line help}; add_parsers(sub) adds them in full.
GROUPS = (process, synth, service, cameras, bench_cli)


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The ``signmap`` parser. ``command``: the command about to run; only its group is built in
    full, the others are listed by name and help. None: every group in full."""
    parser = argparse.ArgumentParser(prog="signmap", description=DESCRIPTION,
                                     epilog=EXIT_CODES_HELP,
                                     formatter_class=HelpFormatter)
    parser.set_defaults(func=show_help(parser))
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for group in GROUPS:
        if command is None or command in group.COMMANDS:
            group.add_parsers(sub)
        else:
            for name, help in group.COMMANDS.items():
                sub.add_parser(name, help=help)
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    # The command is the first word that is not an option ("" when there is none: --help).
    command = next((a for a in argv if not a.startswith("-")), "")
    args = build_parser(command).parse_args(argv)
    return int(args.func(args) or 0)


if __name__ == "__main__":
    sys.exit(main())
