"""Calibration candidates share their frames' SIFT (``colmap.sift_cache``): a candidate's database
written from the journey's cache must be the one COLMAP writes when it extracts the candidate's
images itself, matches included, or the cache would change what the candidates map."""

import sqlite3
from pathlib import Path

import pytest

from app.pipeline.colmap.presets import ProcessOptions, SiftOptions
from app.pipeline.colmap.sfm import SfmJob
from tests.utils.journeys import sliding_frames

TABLES = ("cameras", "rigs", "rig_sensors", "frames", "frame_data", "images", "keypoints",
          "descriptors", "matches", "two_view_geometries")


def _tables(database: Path) -> dict[str, list[tuple]]:
    with sqlite3.connect(database) as db:
        return {t: db.execute(f"SELECT * FROM {t} ORDER BY 1").fetchall() for t in TABLES}


def test_a_candidate_database_from_the_cache_is_the_one_extraction_writes(tmp_path):
    pycolmap = pytest.importorskip("pycolmap")
    from app.pipeline.colmap.sfm import _extract_and_match

    images = tmp_path / "images"
    images.mkdir()
    names = sliding_frames(images, 10)
    (images / names[7]).write_bytes(b"not a PNG")  # COLMAP skips it: so must the cache
    cache = tmp_path / "cache.db"

    def job(extract: list[str], workdir: str, feature_cache: Path | None) -> SfmJob:
        (tmp_path / workdir).mkdir()
        return SfmJob(image_dir=images, workdir=tmp_path / workdir, extract_names=extract,
                      windows=[], sift=SiftOptions(max_features=500, overlap=3),
                      process=ProcessOptions(threads=1), feature_cache=feature_cache)

    # An earlier candidate fills the cache with frames 0-5; the next one needs 3-9.
    first = job(names[:6], "first", cache)
    _extract_and_match(pycolmap, first, first.workdir / "features.db")
    second = job(names[3:], "second", cache)
    _extract_and_match(pycolmap, second, second.workdir / "features.db")
    alone = job(names[3:], "alone", None)
    _extract_and_match(pycolmap, alone, alone.workdir / "features.db")

    from_cache, extracted = (_tables(second.workdir / "features.db"),
                             _tables(alone.workdir / "features.db"))
    assert len(extracted["images"]) == 6 and len(extracted["matches"]) > 0
    assert all(row[1] > 100 for row in extracted["keypoints"])  # features, not empty rows
    for table in TABLES:
        assert from_cache[table] == extracted[table], table
    with sqlite3.connect(cache) as db:  # frames 3-5 were not extracted twice
        assert db.execute("SELECT COUNT(*) FROM images").fetchone()[0] == 9
