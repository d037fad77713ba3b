"""Camera subcommands of ``signmap``: ``cameras set`` registers a camera's known calibration,
``cameras show`` prints what the service knows of a camera, ``cameras list`` the cameras. They
work on the configured database directly, as ``signmap keys`` does (``SIGNMAP_DATABASE_URL``,
default SQLite under ``SIGNMAP_DATA_DIR``)."""

from __future__ import annotations

import argparse
import getpass
import json
import sys

from app.commands.usage import EXIT_BAD_INPUT

COMMANDS = {"cameras": "cameras: `signmap cameras set CAMERA_ID cam.json`, `show`, `list`"}

CALIBRATION_FILE = ("a JSON object with width and height (the frames' size), fx, fy, cx, cy (focal "
                    "lengths and principal point, pixels of the original frames) and optionally "
                    "k1, k2 (OpenCV's radial distortion) and sigma (an object with the same six "
                    "keys: each one's 1-sigma), e.g. {\"width\": 1920, \"height\": 1080, "
                    "\"fx\": 1000, \"fy\": 1000, \"cx\": 960, \"cy\": 540, \"k1\": -0.1, "
                    "\"k2\": 0.01}")


def _read(path: str) -> object:
    try:
        with open(path, encoding="utf-8") as f:
            return json.load(f)
    except OSError as exc:
        raise ValueError(f"cannot read {path}: {exc.strerror or exc}") from None
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ValueError(f"{path} is not valid JSON: {exc}") from None


def cameras_set(args: argparse.Namespace) -> int:
    from pydantic import ValidationError

    from app.commands.service import usable_database
    from app.service.jobs import cameras

    where = "signmap cameras set"
    try:
        cameras.check_camera_id(args.camera_id)
    except cameras.InvalidCalibration as exc:
        print(f"{where}: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    try:
        reg = cameras.Registration.model_validate(_read(args.file))
    except ValueError as exc:  # ValidationError too
        lines = ([f"  {'.'.join(str(p) for p in e['loc']) or '(file)'}: "
                  f"{e['msg'].removeprefix('Value error, ')}"
                  for e in exc.errors()] if isinstance(exc, ValidationError) else [f"  {exc}"])
        print(f"{where}: {args.file} is not a calibration this camera can have:\n"
              + "\n".join(lines) + f"\nIt must be {CALIBRATION_FILE}.", file=sys.stderr)
        return EXIT_BAD_INPUT
    settings = usable_database("cameras set")
    url = settings.effective_database_url
    try:
        epoch, new = cameras.register(url, args.camera_id, reg,
                                      f"signmap cameras set ({getpass.getuser()})")
    except cameras.InvalidCalibration as exc:
        print(f"{where}: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    if not new:
        print(f"camera {args.camera_id}: this calibration is registered already (epoch "
              f"{epoch}); nothing changed")
        return 0
    print(f"camera {args.camera_id}: calibration registered as epoch {epoch}: fx {reg.fx:g}, "
          f"fy {reg.fy:g}, cx {reg.cx:g}, cy {reg.cy:g}, k1 {reg.k1:g}, k2 {reg.k2:g} "
          f"({reg.width}x{reg.height})")
    _resume(settings, args.camera_id, (reg.width, reg.height))
    return 0


def _resume(settings, camera_id: str, size: tuple[int, int]) -> None:
    """Queue the camera's waiting journeys again: sent to the broker when there is one; without,
    the embedded worker of `signmap serve` finds them queued at its next sweep."""
    from app.service.jobs import cameras

    queue = None
    if settings.broker_url:
        from worker.queue import CeleryQueue

        queue = CeleryQueue(settings)
    try:
        reprocess = cameras.reprocess_superseded(settings.effective_database_url, camera_id,
                                                 queue.submit if queue else None)
        if reprocess:
            print(f"{len(reprocess)} done journeys given another calibration of it are queued "
                  f"to be processed again with it: {', '.join(reprocess)}")
        ids = cameras.wake_waiting(settings.effective_database_url, camera_id, size,
                                   queue.submit if queue else None)
    except Exception as exc:  # noqa: BLE001 - the broker is down: the workers' sweeps wake them
        print(f"its waiting journeys were not queued again now ({type(exc).__name__}: {exc}); "
              f"the workers do it at their next sweep", file=sys.stderr)
        return
    finally:
        if queue is not None:
            queue.stop()
    if ids:
        how = ("sent to the workers" if queue else
               "the service's embedded worker runs them from its next sweep (within "
               f"{max(1.0, settings.stale_after_s / 2):g} s)")
        many = len(ids) != 1
        print(f"{len(ids)} journey{'s' if many else ''} waiting for it {'are' if many else 'is'} "
              f"queued again ({how}): {', '.join(ids)}")


def cameras_show(args: argparse.Namespace) -> int:
    from app.commands.service import usable_database
    from app.service.db.session import session_scope
    from app.service.jobs import camera_view

    settings = usable_database("cameras show")
    with session_scope(settings.effective_database_url) as session:
        view = camera_view.camera_view(session, args.camera_id, settings)
        answer = camera_view.to_json(view) if view is not None else None
    if answer is None:
        raise SystemExit(f"signmap cameras show: no camera {args.camera_id} (no journey has it "
                         f"and no calibration was registered for it; `signmap cameras list`)")
    print(json.dumps(answer, indent=2, default=str))
    return 0


def cameras_list(args: argparse.Namespace) -> int:
    from app.commands.service import usable_database
    from app.service.db.session import session_scope
    from app.service.jobs import camera_view

    settings = usable_database("cameras list")
    rows = []
    with session_scope(settings.effective_database_url) as session:
        for camera_id in camera_view.camera_ids(session):
            view = camera_view.camera_view(session, camera_id, settings)
            if view is None:
                continue
            c = camera_view.to_json(view)
            rows.append((camera_id, c["source"] or "-", str(c["epoch"] or "-"),
                         f"{c['calibration']['fx']:.1f}" if c["calibration"] else "-",
                         str(c["journeys"]), str(len(c["left_out"])), str(c["waiting"])))
    table = [("CAMERA", "CALIBRATION", "EPOCH", "FX", "JOURNEYS", "LEFT OUT", "WAITING"), *rows]
    widths = [max(len(row[i]) for row in table) for i in range(len(table[0]))]
    for row in table:
        print("  ".join(cell.ljust(width) for cell, width in zip(row, widths)).rstrip())
    return 0


def add_parsers(sub) -> None:
    from app.commands.usage import show_help

    p = sub.add_parser("cameras", help=COMMANDS["cameras"],
                       description="The cameras the service knows: register a camera's known "
                       "calibration, and see what the service knows of a camera (its "
                       "calibration, the journeys in it and left out, those waiting for it, its "
                       "epochs).")
    p.set_defaults(func=show_help(p))
    cameras_sub = p.add_subparsers(dest="cameras_command", metavar="COMMAND")
    q = cameras_sub.add_parser(
        "set", help="register a camera's calibration from a JSON file",
        description="Registers the calibration in FILE as camera CAMERA_ID's: it starts a new "
        "epoch and is used as given for the camera's later journeys, and the camera's journeys "
        "waiting for a calibration are queued again. The same as PUT "
        "/api/v1/cameras/{camera_id}/calibration with FILE as the body. FILE: "
        + CALIBRATION_FILE.replace("%", "%%") + ".")
    q.add_argument("camera_id", metavar="CAMERA_ID", help="the manifest's camera_id")
    q.add_argument("file", metavar="FILE", help="the calibration, JSON (e.g. cam.json)")
    q.set_defaults(func=cameras_set)
    q = cameras_sub.add_parser(
        "show", help="print what the service knows of a camera (JSON)",
        description="Prints what GET /api/v1/cameras/{camera_id} answers an admin: the "
        "calibration the camera's journeys are given and its sigmas, the journeys in it and "
        "those left out with the reason, the journeys waiting for it, and its epochs.")
    q.add_argument("camera_id", metavar="CAMERA_ID", help="the manifest's camera_id")
    q.set_defaults(func=cameras_show)
    q = cameras_sub.add_parser("list", help="list the cameras, one line each",
                               description="Lists every camera the service knows: its "
                               "calibration's source and epoch, fx, the journeys in it and left "
                               "out, and those waiting for it.")
    q.set_defaults(func=cameras_list)
