"""OpenCV's SIFT written into COLMAP's database (``colmap.cv_sift``) must put each feature where
COLMAP's own extractor puts it (COLMAP's pixel convention, OpenCV's quarter pixel undone), and
give COLMAP pairs it can match and verify."""

import sqlite3
from pathlib import Path

import cv2
import numpy as np
import pytest

from app.pipeline.colmap.presets import ProcessOptions, SiftOptions
from app.pipeline.colmap.sfm import SfmJob
from app.pipeline.types import CameraModel
from tests.utils.journeys import sliding_frames

SHIFT_PX = 40  # the scene slides this far left from one frame to the next


def _features(database: Path) -> tuple[np.ndarray, np.ndarray]:
    """The first image's (K, 2) COLMAP keypoint positions and (K, 128) descriptors."""
    with sqlite3.connect(database) as db:
        rows, cols, kp = db.execute("SELECT rows, cols, data FROM keypoints "
                                    "WHERE image_id = 1").fetchone()
        drows, dcols, desc = db.execute("SELECT rows, cols, data FROM descriptors "
                                        "WHERE image_id = 1").fetchone()
    return (np.frombuffer(kp, np.float32).reshape(rows, cols)[:, :2],
            np.frombuffer(desc, np.uint8).reshape(drows, dcols))


def _job(images: Path, workdir: Path, names: list[str], extractor: str,
         camera: CameraModel | None = None) -> SfmJob:
    workdir.mkdir()
    return SfmJob(image_dir=images, workdir=workdir, extract_names=names, windows=[],
                  sift=SiftOptions(max_features=1000, overlap=2, extractor=extractor),
                  process=ProcessOptions(threads=1), camera=camera)


def test_opencv_features_sit_where_colmap_puts_them_and_match(tmp_path):
    pycolmap = pytest.importorskip("pycolmap")
    from app.pipeline.colmap.sfm import _extract_and_match

    images = tmp_path / "images"
    images.mkdir()
    names = sliding_frames(images, 4, SHIFT_PX)
    camera = CameraModel(640, 480, 500.0, 500.0, 319.5, 239.5, 0.0, 0.0)
    colmap = _job(images, tmp_path / "colmap", names, "colmap")
    _extract_and_match(pycolmap, colmap, colmap.workdir / "features.db")
    opencv = _job(images, tmp_path / "opencv", names, "opencv", camera)
    _extract_and_match(pycolmap, opencv, opencv.workdir / "features.db")

    # The same features by descriptor (mutual nearest neighbours), then their positions.
    xy_colmap, d_colmap = _features(colmap.workdir / "features.db")
    xy_opencv, d_opencv = _features(opencv.workdir / "features.db")
    matches = cv2.BFMatcher(cv2.NORM_L2, crossCheck=True).match(
        d_opencv.astype(np.float32), d_colmap.astype(np.float32))
    offset = np.array([xy_opencv[m.queryIdx] - xy_colmap[m.trainIdx] for m in matches])
    same = np.linalg.norm(offset, axis=1) < 2.0
    assert same.sum() > 200
    assert np.all(np.abs(np.median(offset[same], axis=0)) < 0.05)

    # COLMAP matches and verifies them: each verified pair moved by the scene's shift.
    with sqlite3.connect(opencv.workdir / "features.db") as db:
        kp = {i: np.frombuffer(d, np.float32).reshape(r, c)[:, :2]
              for i, r, c, d in db.execute("SELECT image_id, rows, cols, data FROM keypoints")}
        pairs = db.execute("SELECT pair_id, rows, data FROM two_view_geometries "
                           "WHERE rows > 0").fetchall()
    assert len(pairs) == 5  # frames 0-1, 0-2, 1-2, 1-3, 2-3
    for pair_id, rows, data in pairs:
        id2 = pair_id % 2147483647
        id1 = (pair_id - id2) // 2147483647
        m = np.frombuffer(data, np.uint32).reshape(rows, 2)
        dx = kp[id2][m[:, 1]] - kp[id1][m[:, 0]]
        assert rows > 100
        assert np.median(np.abs(dx[:, 0] + SHIFT_PX * (id2 - id1))) < 0.1
        assert np.median(np.abs(dx[:, 1])) < 0.1
    with pycolmap.Database.open(opencv.workdir / "features.db") as db:
        known, = db.read_all_cameras()  # the pairs were verified with the camera given
    assert known.has_prior_focal_length and known.params[0] == 500.0
