"""``signmap bench [--quick]``, ``signmap bench sensitivity`` and ``signmap bench fusion``: argument
parsing only."""

from __future__ import annotations

import argparse
from pathlib import Path

BENCH_DIR = Path(__file__).resolve().parent


def _common(p: argparse.ArgumentParser, inherit: bool = False) -> None:
    """The shared options; ``inherit``: a subcommand keeps what was given before its name
    (``bench --quick sensitivity``) unless given again."""
    def default(value):
        return argparse.SUPPRESS if inherit else value
    p.add_argument("--quick", action="store_true", default=default(False),
                   help="small journeys and fewer variants (a few minutes)")
    p.add_argument("--out", type=Path, default=default(BENCH_DIR / "results"),
                   help="where the markdown, JSON and PNG results go")
    p.add_argument("--cache", type=Path, default=default(BENCH_DIR / "cache"),
                   help="rendered synthetic journeys, reused between runs")


def run_suite_command(args) -> int:
    from bench.runner import run_bench

    md, js = run_bench(quick=args.quick, out_dir=args.out, cache_dir=args.cache)
    print(md.read_text())
    print(f"wrote {md} and {js}")
    return 0


def run_sensitivity_command(args) -> int:
    from bench.sensitivity import run_sensitivity

    md, js = run_sensitivity(quick=args.quick, out_dir=args.out, cache_dir=args.cache,
                             steps=args.steps)
    print(md.read_text())
    print(f"wrote {md} and {js}")
    return 0


def run_fusion_command(args) -> int:
    from bench.fusion import run_fusion

    md, js = run_fusion(quick=args.quick, out_dir=args.out, cache_dir=args.cache)
    print(md.read_text())
    print(f"wrote {md} and {js}")
    return 0


def add_parsers(sub) -> None:
    """Add ``bench`` (with its ``sensitivity`` and ``fusion`` subcommands) to the ``signmap``
    subparsers."""
    p = sub.add_parser("bench", help="benchmark accuracy and speed on synthetic journeys",
                       description="Runs the suite of synthetic journeys with our pipeline and "
                       "its baselines; prints markdown tables, writes <date>.md/.json and plots.")
    _common(p)
    p.set_defaults(func=run_suite_command)
    bench_sub = p.add_subparsers(dest="bench_command")
    s = bench_sub.add_parser("sensitivity", help="one-at-a-time camera error study (paper Fig. 3)")
    _common(s, inherit=True)
    s.add_argument("--steps", type=int, default=5, help="error steps from -15 %% to +15 %%")
    s.set_defaults(func=run_sensitivity_command)
    f = bench_sub.add_parser("fusion", help="map error vs number of journeys fused (issue 5)")
    _common(f, inherit=True)
    f.set_defaults(func=run_fusion_command)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench")
    add_parsers(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(["bench", *(argv or [])])
    return int(args.func(args) or 0)
