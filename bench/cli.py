"""``signmap bench [--quick]``, ``signmap bench sensitivity``, ``signmap bench fusion`` and
``signmap bench corpus``, ``signmap bench render-check`` and ``signmap bench map``: argument
parsing only."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

SCENARIOS = ("pages", "big-pages", "tiles", "low-tiles")  # bench.service.map_load.SCENARIOS

BENCH_DIR = Path(__file__).resolve().parent

COMMANDS = {"bench": "benchmark accuracy and speed on synthetic journeys"}


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
    from bench.paper.runner import run_bench

    md, js = run_bench(quick=args.quick, out_dir=args.out, cache_dir=args.cache)
    print(md.read_text())
    print(f"wrote {md} and {js}")
    return 0


def run_sensitivity_command(args) -> int:
    from bench.paper.sensitivity import run_sensitivity

    md, js = run_sensitivity(quick=args.quick, out_dir=args.out, cache_dir=args.cache,
                             steps=args.steps)
    print(md.read_text())
    print(f"wrote {md} and {js}")
    return 0


def run_fusion_command(args) -> int:
    from bench.paper.fusion import run_fusion

    md, js = run_fusion(quick=args.quick, out_dir=args.out, cache_dir=args.cache)
    print(md.read_text())
    print(f"wrote {md} and {js}")
    return 0


def run_render_check_command(args) -> int:
    from bench.studies.render_check import run_render_check

    md = run_render_check(args.corpus, args.names, args.out)
    print(f"wrote {md}")
    return 0


def parse_knob(text: str) -> tuple[str, object]:
    """``knob=value`` of ``--set``: the value as JSON (numbers, true, lists), else a string."""
    knob, sep, value = text.partition("=")
    if not sep or not knob:
        raise argparse.ArgumentTypeError(f"expected knob=value, got {text!r}")
    try:
        return knob.strip(), json.loads(value)
    except json.JSONDecodeError:
        return knob.strip(), value


def run_corpus_command(args) -> int:
    from bench.corpus.run import run_corpus

    if args.true_camera and args.stored_camera:
        raise SystemExit("signmap bench corpus: --true-camera skips calibrating, --stored-camera "
                         "calibrates beside a stored camera: give one")
    if args.true_camera_focal_scale != 1.0 and not (args.true_camera or args.stored_camera):
        raise SystemExit("signmap bench corpus: --true-camera-focal-scale scales the true camera: "
                         "give --true-camera or --stored-camera too")
    try:
        paths = run_corpus(args.corpus, args.out, half=args.half, limit=args.limit,
                           names=[n for n in (args.names or "").split(",") if n] or None,
                           calibrate_only=args.calibrate_only, true_camera=args.true_camera,
                           config_overrides=dict(args.set or []), tag=args.tag,
                           resume=args.resume, keep_dir=args.keep_reconstructions,
                           replay_dir=args.replay, focal_scale=args.true_camera_focal_scale,
                           stored_camera=args.stored_camera, as_video=args.as_video,
                           antenna_undeclared=args.antenna_undeclared, gps_jump=args.gps_jump)
    except (ValueError, FileNotFoundError) as exc:  # a wrong argument or corpus: say which
        raise SystemExit(f"signmap bench corpus: {exc}") from exc
    print(paths.markdown.read_text())
    print(f"wrote {paths.markdown}, {paths.json}, {paths.png} and {paths.jsonl}")
    return 0


def _runs(command: str, paths: list[Path]) -> list[dict]:
    """The journey records of the corpus runs ``paths``, pooled; a missing file ends ``command``."""
    from bench.corpus.run import read_records

    missing = [str(p) for p in paths if not p.is_file()]
    if missing:
        raise SystemExit(f"signmap bench {command}: no such file: {', '.join(missing)}")
    return read_records(paths)


def run_uncertainty_command(args) -> int:
    from app.pipeline.config import PipelineConfig
    from bench.studies.uncertainty_fit import Knobs, report

    records = _runs("uncertainty", args.jsonl)
    c = PipelineConfig()
    fitted, table = report(records, Knobs(c.sign_georef_floor_m, c.sign_georef_noise_gain,
                                          c.sign_georef_bias_quad_per_m))
    print(table)
    print(f"\nfitted on the tuning half: --set sign_georef_floor_m={fitted.floor_m:.2f} "
          f"--set sign_georef_bias_quad_per_m={fitted.bias_quad_per_m:.2f}")
    return 0


def run_corpus_compare_command(args) -> int:
    from bench.corpus.compare import compare

    before = _runs("corpus-compare", args.before)
    print(compare(before, _runs("corpus-compare", args.after)))
    return 0


def run_corpus_report_command(args) -> int:
    from bench.corpus.report import render_records

    md = render_records(_runs("corpus-report", args.jsonl), [str(p) for p in args.jsonl])
    if args.out:
        args.out.write_text(md)
    print(md)
    return 0


def run_turns_command(args) -> int:
    from bench.studies.turn_detection import run

    try:
        print(run(args.n, args.seed, args.variant or [], args.half))
    except ValueError as exc:
        raise SystemExit(f"signmap bench turns: {exc}") from exc
    return 0


def _add_turns_parser(bench_sub) -> None:
    t = bench_sub.add_parser(
        "turns", help="the turn finder against the truth over corpus journeys (no rendering)",
        description="Draws the journeys `signmap synth corpus --n N --seed S` would render, "
        "without their pixels, and prints per variant and half the journeys with a true turn "
        "of 45 deg or more where no turn is found and the gentle ones where one is; with a "
        "variant, also the journeys whose calibration candidate frames it moves.")
    t.add_argument("--n", type=int, default=64, help="journeys (default 64)")
    t.add_argument("--seed", type=int, default=0, help="first seed (default 0)")
    t.add_argument("--half", choices=("tuning", "check"), help="one half only")
    t.add_argument("--variant", action="append", metavar="NAME:KNOB=VALUE,...",
                   help="a row besides the defaults (repeatable)")
    t.set_defaults(func=run_turns_command)


def run_gps_draws_command(args) -> int:
    from pydantic import ValidationError

    from bench.studies.gps_draws import run

    try:
        print(run(args.journey, args.draws, args.variant or [], args.cache, args.seed))
    except (ValueError, ValidationError) as exc:
        raise SystemExit(f"signmap bench gps-draws: {exc}") from exc
    return 0


def _add_gps_draws_parser(bench_sub) -> None:
    g = bench_sub.add_parser(
        "gps-draws", help="a suite journey's sign errors over fresh draws of its GPS noise, "
        "variants compared draw by draw",
        description="Reconstructs a suite journey once per variant with its true camera, then "
        "georeferences it under the same fresh draws of its GPS noise model and prints, per "
        "variant, the sign errors' distribution over the draws and the paired difference to "
        "the defaults: one draw's bias decides a single run's absolute error.")
    g.add_argument("--cache", type=Path, default=BENCH_DIR / "cache",
                   help="rendered synthetic journeys, reused between runs")
    g.add_argument("--journey", default="loop-300", help="a suite journey (default loop-300)")
    g.add_argument("--draws", type=int, default=30,
                   help="fresh GPS draws per journey (default 30)")
    g.add_argument("--seed", type=int, action="append",
                   help="the journey re-seeded: another world and other noise of the same kind "
                   "(repeatable: their draws are pooled)")
    g.add_argument("--variant", action="append", metavar="NAME:KNOB=VALUE,...",
                   help="a variant besides the defaults (repeatable)")
    g.set_defaults(func=run_gps_draws_command)


def run_gps_scale_command(args) -> int:
    from bench.studies.gps_scale import run

    print(run(args.n, args.seed, args.half))
    return 0


def _add_gps_scale_parser(bench_sub) -> None:
    g = bench_sub.add_parser(
        "gps-scale", help="window scale error from GPS alone, straight lines vs spline "
        "between fixes, over corpus journeys (no rendering)",
        description="Draws the journeys `signmap synth corpus --n N --seed S` would render, "
        "without their pixels, fits each ego-motion-sized window of true camera centres to its "
        "frames' GPS positions, and prints the scale error per GPS kind, half and way of placing "
        "frames between fixes.")
    g.add_argument("--n", type=int, default=64, help="journeys (default 64)")
    g.add_argument("--seed", type=int, default=0, help="first seed (default 0)")
    g.add_argument("--half", choices=("tuning", "check"), help="one half only")
    g.set_defaults(func=run_gps_scale_command)


def run_gps_focal_command(args) -> int:
    from bench.studies.gps_focal import collect, table, window_rotation_table

    if not args.records and not args.replay:
        raise SystemExit("signmap bench gps-focal: give --replay DIR or --records RUN.jsonl")
    if args.records:
        print(window_rotation_table(args.records, args.corpus))
    if args.replay:
        print(table(collect(args.replay, args.corpus)))
    return 0


def _add_gps_focal_parser(bench_sub) -> None:
    g = bench_sub.add_parser(
        "gps-focal", help="can the GPS check the focal length? kept reconstructions' turning "
        "windows unbent to fit the GPS (a study)",
        description="For each journey kept by `bench corpus --keep-reconstructions`, the "
        "rotation scale (fx_true / fx used) that best fits its turning ego-motion windows to its "
        "GPS and to the true camera centres, beside the true one.")
    g.add_argument("--replay", type=Path, action="append",
                   help="a --keep-reconstructions directory (repeatable)")
    g.add_argument("--records", type=Path, help="a `bench corpus` run's .jsonl: print each "
                   "accepted calibration window's rotation beside the GPS heading's range over it")
    g.add_argument("--corpus", type=Path, required=True, help="the corpus directory (truth)")
    g.set_defaults(func=run_gps_focal_command)


def run_pose_error_command(args) -> int:
    from bench.studies.pose_error import collect, table

    print(table(collect(args.replay, args.corpus)))
    return 0


def run_real_ego_command(args) -> int:
    from bench.studies.real_ego import run

    print(run(args.bundle, args.calibration, args.poses))
    return 0


def _add_real_ego_parser(bench_sub) -> None:
    g = bench_sub.add_parser(
        "real-ego", help="ego-motion over a whole real drive with its known camera, against its "
        "true poses",
        description="Maps every frame of a journey bundle as ego-motion maps the frames around "
        "a sign, with the camera given, and prints per window the registration, the relative "
        "rotation and translation direction errors and the scale drift against the true poses "
        "(e.g. ../shared/real/kitti0009_poses.json).")
    g.add_argument("bundle", help="the journey bundle (.zip)")
    g.add_argument("--calibration", required=True, help="the camera, a JSON {fx, fy, cx, cy, ...}")
    g.add_argument("--poses", help="the true poses: JSON {frames: [{frame, T_world_cam}]}, or "
                   "{T_enu_cam: [...]} one per frame in order")
    g.set_defaults(func=run_real_ego_command)


def _add_pose_error_parser(bench_sub) -> None:
    g = bench_sub.add_parser(
        "pose-error", help="split each placed sign's relative error into what the detections, "
        "the estimated rotations and the estimated centres cost",
        description="Georeferences again the reconstructions a corpus run kept "
        "(--keep-reconstructions) and triangulates each placed sign from its detections with "
        "the true poses, estimated rotations with true centres, and true rotations with "
        "estimated centres; prints the mean relative error of each per GPS kind.")
    g.add_argument("--replay", type=Path, required=True,
                   help="the directory a corpus run's --keep-reconstructions wrote")
    g.add_argument("--corpus", type=Path, required=True, help="the corpus it ran on (truth)")
    g.set_defaults(func=run_pose_error_command)


def run_video_command(args) -> int:
    from bench.studies.video_decode import run_video_bench

    md = run_video_bench(args.seconds, args.out, args.size, args.fps)
    print(md.read_text())
    print(f"wrote {md}")
    return 0


def _add_video_parser(bench_sub) -> None:
    g = bench_sub.add_parser(
        "video", help="a video journey's intake: decode and frame choice per minute of 1080p30",
        description="Encodes a 1080p30 H.264 video of a panning texture, then times, each in its "
        "own process, a plain decode (the baseline) and the worker's intake (decode, keep 10 Hz, "
        "write JPEG, image motion for the clock offset); prints seconds per minute of video, "
        "their ratio and peak memory.")
    g.add_argument("--seconds", type=float, default=20.0,
                   help="length of the video made (default: %(default)s)")
    g.add_argument("--size", choices=("1080p", "4k"), default="1080p",
                   help="frame size (default: %(default)s)")
    g.add_argument("--fps", type=int, default=30, help="frame rate (default: %(default)s)")
    g.set_defaults(func=run_video_command)


def run_detector_command(args) -> int:
    from bench.cost.detector_time import BenchError, run_detector_bench

    try:
        md = run_detector_bench(args.frames, args.out, args.size)
    except BenchError as exc:
        raise SystemExit(f"signmap bench detector: {exc}") from exc
    print(md.read_text())
    print(f"wrote {md}")
    return 0


def _add_detector_parser(bench_sub) -> None:
    g = bench_sub.add_parser(
        "detector", help="the sign detector's time per frame at 640 px on 2 threads",
        description="Builds a convolutional ONNX detector of a realistic size (YOLOv8-like "
        "output [1, 4+nc, 8400], random weights; needs the onnx package, a test extra) and runs "
        "it through the worker's detector on JPEG frames; prints ms per frame for letterbox, "
        "inference, decode + NMS and the whole, against reading the JPEG frame.")
    g.add_argument("--frames", type=int, default=20, help="frames timed (default: %(default)s)")
    g.add_argument("--size", choices=("1080p", "1242x375"), default="1080p",
                   help="frame size (default: %(default)s)")
    g.add_argument("--out", type=Path, default=argparse.SUPPRESS,
                   help="where the markdown goes (default bench/results)")
    g.set_defaults(func=run_detector_command)


def _add_corpus_parser(bench_sub) -> None:
    c = bench_sub.add_parser("corpus", help="self-calibration and signs over a generated corpus",
                             description="Runs the pipeline on the journeys of a corpus written "
                             "by `signmap synth corpus`; writes <date>-corpus<tag>.jsonl/.md/"
                             ".json/.png.")
    c.add_argument("--corpus", type=Path, required=True, help="the corpus directory")
    c.add_argument("--half", choices=("tuning", "check"), help="run one half only")
    c.add_argument("--limit", type=int, help="the first N selected journeys only")
    c.add_argument("--names", help="comma-separated journey names")
    c.add_argument("--calibrate-only", action="store_true",
                   help="drop the detections: the pipeline stops after calibrating")
    c.add_argument("--true-camera", action="store_true",
                   help="give the pipeline each journey's true camera instead of self-calibrating "
                        "(measures sign placement on every journey, those without turns too)")
    c.add_argument("--stored-camera", action="store_true",
                   help="hand the true camera over as the camera's stored calibration, as the "
                        "service does for a known camera; the journey still calibrates itself")
    c.add_argument("--true-camera-focal-scale", type=float, default=1.0, metavar="F",
                   help="with --true-camera or --stored-camera: hand over fx and fy times F "
                        "(0.97: a calibration "
                        "3 %% short), to see what a focal error does to the later stages")
    c.add_argument("--as-video", action="store_true",
                   help="run each journey as the video bundle a dash cam would upload (H.264 "
                        "video.mp4 + gps.nmea, its clock off GPS time by a few whole seconds "
                        "drawn from the journey's name, undeclared): records the clock error "
                        "estimated against the true one")
    c.add_argument("--antenna-undeclared", action="store_true",
                   help="leave each bundle's gps_antenna_offset_m out of its manifest (a corpus "
                        "rendered with --antenna-offsets): the pipeline must estimate the offset, "
                        "and the records compare its estimate with the true one")
    c.add_argument("--gps-jump", action="store_true",
                   help="move a run of each journey's GPS fixes 4-10 m off for 1.5-3 s, drawn "
                        "from its name (multipath by a building): the window around it disagrees "
                        "with the GPS, and the records say whether it was mended")
    c.add_argument("--set", type=parse_knob, action="append", metavar="KNOB=VALUE",
                   help="override a PipelineConfig knob (repeatable)")
    c.add_argument("--tag", default="", help="appended to the output names: <date>-corpus-<tag>")
    c.add_argument("--resume", action="store_true",
                   help="continue the latest run of this tag, skipping journeys it has")
    c.add_argument("--keep-reconstructions", type=Path, metavar="DIR",
                   help="keep each journey's reconstruction (up to ego-motion) in DIR")
    c.add_argument("--replay", type=Path, metavar="DIR",
                   help="only align and triangulate again, on the reconstructions kept in DIR "
                        "(seconds per journey; only knobs of those stages may differ)")
    c.add_argument("--out", type=Path, default=argparse.SUPPRESS,
                   help="where the results go (default bench/results)")
    c.set_defaults(func=run_corpus_command)


def run_fleet_command(args) -> int:
    from bench.corpus.fleet import run_fleet

    try:
        md = run_fleet(args.corpus, args.out, args.keep, half=args.half,
                       agree_rel=args.agree_rel, tag=args.tag, again=args.again)
    except (ValueError, FileNotFoundError) as exc:
        raise SystemExit(f"signmap bench fleet: {exc}") from exc
    print(md.read_text())
    print(f"wrote {md} and {md.with_suffix('.json')}")
    return 0


def _add_fleet_parser(bench_sub) -> None:
    f = bench_sub.add_parser(
        "fleet", help="a camera calibrated jointly from its journeys, on a fleet corpus",
        description="Calibrates each journey of a fleet corpus (`signmap synth corpus "
        "--cameras`) alone, then each camera jointly from its journeys, after each journey, "
        "beside the consensus of its calibrations, and each camera's first and second journey "
        "side by side (the second self-calibrating, and checking the camera the first "
        "calibrated on its turn); with --again, every journey in full with its true camera and "
        "processed again with its camera's joint calibration; writes <date>-fleet<tag>.md/.json.")
    f.add_argument("--corpus", type=Path, required=True, help="the fleet corpus directory")
    f.add_argument("--half", choices=("tuning", "check"), help="one half only (by camera)")
    f.add_argument("--keep", type=Path, required=True, metavar="DIR",
                   help="each journey's calibration and window are kept here and reused")
    f.add_argument("--agree-rel", type=float, default=0.03,
                   help="calibrations within this share of each other agree (default 0.03)")
    f.add_argument("--again", action="store_true",
                   help="also run every journey in full, with its true camera and processed again "
                   "with its camera's joint calibration (kept in --keep; ~1 min a journey)")
    f.add_argument("--tag", default="", help="appended to the output names")
    f.add_argument("--out", type=Path, default=argparse.SUPPRESS,
                   help="where the results go (default bench/results)")
    f.set_defaults(func=run_fleet_command)


def run_map_command(args) -> int:
    import sys

    from bench.service.map_bench import QUICK_SIGNS, MapBenchOptions, run_map_bench

    quick = args.quick
    opts = MapBenchOptions(
        signs=args.signs if args.signs is not None else (QUICK_SIGNS if quick else 1_000_000),
        sqlite_signs=(args.sqlite_signs if args.sqlite_signs is not None
                      else (QUICK_SIGNS if quick else 100_000)),
        postgres_url=None if args.no_postgres else args.postgres_url,
        concurrency=tuple(args.concurrency), requests=args.requests or (40 if quick else 400),
        scenarios=tuple(args.scenarios), quick=quick, cache_dir=args.cache, out_dir=args.out, base_url=args.base_url, key=args.key)
    try:
        md, js, _ = run_map_bench(opts, command="signmap bench map " + " ".join(sys.argv[3:]))
    except ValueError as exc:
        raise SystemExit(f"signmap bench map: {exc}") from exc
    print(md.read_text())
    print(f"wrote {md} and {js}")
    return 0


def _int_list(text: str) -> list[int]:
    try:
        values = [int(v) for v in text.split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected numbers like 2,8, got {text!r}") from None
    if not values or min(values) < 1:
        raise argparse.ArgumentTypeError("at least one client")
    return values


def _scenario_list(text: str) -> list[str]:
    values = [v for v in text.split(",") if v]
    unknown = sorted(set(values) - set(SCENARIOS))
    if unknown or not values:
        raise argparse.ArgumentTypeError(f"unknown scenario {', '.join(unknown) or '(none)'}; "
                                         f"choose from {','.join(SCENARIOS)}")
    return values


def _add_map_parser(bench_sub) -> None:
    m = bench_sub.add_parser(
        "map", help="map reads at scale: sign pages and vector tiles under concurrent clients",
        description="Loads N synthetic map signs into PostgreSQL (database "
        "signmap_bench_map_<N>, kept for the next run) and a smaller map into SQLite (under "
        "--cache), starts `signmap serve` on 127.0.0.1 and times GET /signs?bbox= pages of a "
        "city (following `next`), vector tiles at zoom 12-16 and 6-11, and /health meanwhile. "
        "Writes <date>-map.md and .json.")
    m.add_argument("--quick", action="store_true",
                   help="a small map and few requests (seconds; writes <date>-map-quick.md)")
    m.add_argument("--out", type=Path, default=BENCH_DIR / "results",
                   help="where the markdown and JSON results go (default bench/results)")
    m.add_argument("--cache", type=Path, default=BENCH_DIR / "cache",
                   help="where the SQLite map is kept between runs (default bench/cache)")
    m.add_argument("--signs", type=int, default=None,
                   help="map signs on PostgreSQL (default 1,000,000; --quick: 3,000; 0 = skip)")
    m.add_argument("--sqlite-signs", type=int, default=None,
                   help="map signs on SQLite (default 100,000; --quick: 3,000; 0 = skip)")
    m.add_argument("--postgres-url", default="postgresql+psycopg://postgres@127.0.0.1:5432/postgres",
                   help="a PostgreSQL database to connect to for creating the bench's own "
                   "(default: %(default)s)")
    m.add_argument("--no-postgres", action="store_true", help="SQLite only")
    m.add_argument("--concurrency", type=_int_list, default=[1, 2, 8],
                   help="clients at once; a comma-separated list runs each (default 1,2,8)")
    m.add_argument("--scenarios", type=_scenario_list, default=list(SCENARIOS),
                   help=f"comma-separated, of {','.join(SCENARIOS)} (default: all)")
    m.add_argument("--requests", type=int, default=None,
                   help="requests per scenario (default 400; --quick: 40)")
    m.add_argument("--base-url", default=None,
                   help="measure this already running server instead (its map must be the "
                   "synthetic one of --signs); needs --key")
    m.add_argument("--key", default=None, help="a reader key of --base-url's server")
    m.set_defaults(func=run_map_command)


def add_parsers(sub) -> None:
    """Add ``bench`` (with its ``sensitivity``, ``fusion`` and ``corpus`` subcommands) to the
    ``signmap`` subparsers."""
    p = sub.add_parser("bench", help=COMMANDS["bench"],
                       description="Runs the suite of synthetic journeys with our pipeline and "
                       "its baselines; prints markdown tables, writes <date>.md/.json and plots.")
    _common(p)
    p.set_defaults(func=run_suite_command)
    bench_sub = p.add_subparsers(dest="bench_command")
    s = bench_sub.add_parser("sensitivity", help="how camera errors of -15 %% to +15 %% change the sign error")
    _common(s, inherit=True)
    s.add_argument("--steps", type=int, default=5, help="error steps from -15 %% to +15 %%")
    s.set_defaults(func=run_sensitivity_command)
    f = bench_sub.add_parser("fusion", help="map error vs number of journeys fused")
    _common(f, inherit=True)
    f.set_defaults(func=run_fusion_command)
    _add_corpus_parser(bench_sub)
    _add_fleet_parser(bench_sub)
    _add_turns_parser(bench_sub)
    _add_gps_scale_parser(bench_sub)
    _add_gps_draws_parser(bench_sub)
    _add_gps_focal_parser(bench_sub)
    _add_pose_error_parser(bench_sub)
    _add_video_parser(bench_sub)
    _add_detector_parser(bench_sub)
    _add_real_ego_parser(bench_sub)
    u = bench_sub.add_parser(
        "uncertainty", help="fit the sign-uncertainty knobs on a corpus run's tuning half",
        description="Reads the JSONL of a full `signmap bench corpus` run; chooses "
        "sign_georef_floor_m and sign_georef_bias_quad_per_m on its tuning half so that 95 %% of "
        "signs lie inside their 95 %% radius for OXTS-like and phone-like GPS alike; prints the "
        "coverage per half with the current and the fitted knobs.")
    u.add_argument("jsonl", type=Path, nargs="+",
                   help="<date>-corpus<tag>.jsonl of full runs (several: their journeys pooled)")
    u.set_defaults(func=run_uncertainty_command)
    cc = bench_sub.add_parser(
        "corpus-compare", help="two sets of corpus runs side by side (before / after a change)",
        description="Prints the summary rows of the corpus runs in --before and in --after side "
        "by side, per half, over the journeys both ran.")
    cc.add_argument("--before", type=Path, nargs="+", required=True, help="JSONL files")
    cc.add_argument("--after", type=Path, nargs="+", required=True, help="JSONL files")
    cc.set_defaults(func=run_corpus_compare_command)
    cr = bench_sub.add_parser(
        "corpus-report", help="the corpus report of runs already made, pooled",
        description="Reads corpus runs' JSONL files (several: their journeys pooled; a journey "
        "in more than one keeps its last record) and prints the report's tables with the "
        "current report code, without running anything.")
    cr.add_argument("jsonl", type=Path, nargs="+", help="<date>-corpus<tag>.jsonl files")
    cr.add_argument("--out", type=Path, help="also write the markdown here")
    cr.set_defaults(func=run_corpus_report_command)
    rc = bench_sub.add_parser(
        "render-check", help="does each rendered journey's imagery fit its own true camera?",
        description="SIFT matches between frames of each journey's sharpest turn, triangulated "
        "with the true poses and projected through the true camera with fx, fy scaled by "
        "0.98-1.02: a faithful render fits best at 1. Writes <date>-render-check.md.")
    rc.add_argument("--corpus", type=Path, required=True, help="a `signmap synth corpus` directory")
    rc.add_argument("--names", type=lambda t: [n for n in t.split(",") if n], default=None,
                    help="comma-separated journey names (default: all)")
    rc.add_argument("--out", type=Path, default=BENCH_DIR / "results",
                    help="where the markdown goes (default bench/results)")
    rc.set_defaults(func=run_render_check_command)
    _add_map_parser(bench_sub)
    from bench.service.api_load import add_parser as add_api_parser

    add_api_parser(bench_sub)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench")
    add_parsers(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(["bench", *(argv or [])])
    return int(args.func(args) or 0)
