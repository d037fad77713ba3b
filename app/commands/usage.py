"""What every ``signmap`` command shares: its exit statuses and how its help is printed."""

from __future__ import annotations

import argparse

# Exit codes of `signmap` (documented in its --help epilog; 1: any other failure).
EXIT_OK = 0
EXIT_USAGE = 2  # argparse's: an unknown option, a missing argument, a command without a subcommand
EXIT_BAD_INPUT = 3  # a file given does not exist, cannot be read or breaks the wire contract
EXIT_PIPELINE_FAILED = 4  # the input was valid but the pipeline could not process the journey

EXIT_CODES_HELP = f"""\
exit status:
  {EXIT_OK}  success
  1  any other failure, e.g. a service command that cannot start (the message
     says why)
  {EXIT_USAGE}  usage error: an unknown option, a missing argument or subcommand
  {EXIT_BAD_INPUT}  bad input (process): a file given does not exist or cannot be read, or
     the bundle breaks the journey format (docs/journey-format.md); the
     message says what to fix
  {EXIT_PIPELINE_FAILED}  the journey could not be processed (process): e.g. its camera could
     not be calibrated; the message says at which stage and why"""



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
