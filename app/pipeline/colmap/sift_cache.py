"""SIFT features shared between a journey's calibration candidates.

Candidate windows around one turn share about half their frames (tuning halves of seeds 832-895;
docs/decisions/calib-sift-features.md), and SIFT extraction is two thirds of a candidate's time
(c0852: 14-15 s of ~22 s per window, one thread). So every image is extracted once, into the
journey's cache database, and each candidate's own database is written from it: the same rows
COLMAP's extractor writes (one camera, one trivial rig, one frame per image, ids 1..n in the order
of the names), so matching and mapping see exactly what they saw when each candidate extracted its
own (``tests/pipeline/calibration/test_sift_cache.py`` compares the two databases table by
table).

This module reads and writes COLMAP's SQLite schema directly: pycolmap has no call that copies an
image's features between databases.
"""

from __future__ import annotations

import sqlite3
from pathlib import Path
from typing import Callable

CAMERA_SENSOR = 0  # COLMAP's SensorType.CAMERA in rigs / frame_data


def cached_names(cache: Path) -> set[str]:
    """Names of the images whose keypoints and descriptors ``cache`` holds."""
    if not cache.exists():
        return set()
    with sqlite3.connect(cache) as db:
        return {name for (name,) in db.execute(
            "SELECT name FROM images JOIN keypoints USING (image_id) "
            "JOIN descriptors USING (image_id)")}


def extract_into(cache: Path, names: list[str],
                 extract: Callable[[Path, list[str]], None]) -> list[str]:
    """Extract the ``names`` not in ``cache`` yet with ``extract(database, names)``; those names."""
    cached = cached_names(cache)
    missing = [n for n in names if n not in cached]
    if missing:
        extract(cache, missing)
    return missing


def write_database(cache: Path, database: Path, names: list[str]) -> None:
    """Fill ``database`` (new, with COLMAP's schema and nothing in it) with the images ``names``
    and their features from ``cache``, as a fresh extraction of ``names`` would. Names COLMAP
    wrote no image for (it skips frames it cannot read) are left out, as it would leave them."""
    with sqlite3.connect(cache) as src, sqlite3.connect(database) as dst:
        rows = [row for name in names if (row := _image_row(src, name)) is not None]
        if not rows:
            return
        camera = src.execute("SELECT * FROM cameras WHERE camera_id = ?",
                             (rows[0][2],)).fetchone()
        dst.execute(_insert("cameras", camera), (1, *camera[1:]))
        rig = src.execute("SELECT * FROM rigs WHERE ref_sensor_id = ? AND ref_sensor_type = ?",
                          (rows[0][2], CAMERA_SENSOR)).fetchone()
        dst.execute(_insert("rigs", rig), (1, 1, *rig[2:]))
        for image_id, old in enumerate(rows, start=1):
            dst.execute(_insert("images", old), (image_id, old[1], 1, *old[3:]))
            data = src.execute("SELECT * FROM frame_data WHERE data_id = ? AND sensor_type = ?",
                               (old[0], CAMERA_SENSOR)).fetchone()
            frame = src.execute("SELECT * FROM frames WHERE frame_id = ?", (data[0],)).fetchone()
            dst.execute(_insert("frames", frame), (image_id, 1, *frame[2:]))
            dst.execute(_insert("frame_data", data), (image_id, image_id, 1, *data[3:]))
            for table in ("keypoints", "descriptors"):
                row = src.execute(f"SELECT * FROM {table} WHERE image_id = ?", (old[0],)).fetchone()
                if row is not None:
                    dst.execute(_insert(table, row), (image_id, *row[1:]))


def _image_row(db: sqlite3.Connection, name: str) -> tuple | None:
    return db.execute("SELECT * FROM images WHERE name = ?", (name,)).fetchone()


def _insert(table: str, row: tuple) -> str:
    return f"INSERT INTO {table} VALUES ({', '.join('?' * len(row))})"
