"""SIFT by OpenCV, written into a COLMAP database in the rows COLMAP's own extractor writes, so
that COLMAP matches, verifies and maps them as its own (ego-motion's front end).

Why: COLMAP's CPU SIFT took 34 of ``long-600``'s 141 s; OpenCV's extracts faster, and on the
full-size frame (OpenCV always starts one octave up, the image doubled: COLMAP's octave -1) it
placed signs as precisely as COLMAP's octave 0 did (docs/decisions/ego-opencv-sift.md). Runs in
the COLMAP child process (``sfm``).

Positions: OpenCV reports a keypoint found in the doubled image's pixel j at j / 2, where that
pixel's centre lies at j / 2 - 1/4 of the frame; so a reported u sits at u - 1/4 in OpenCV pixels
(centres at integers) and at u + 1/4 in COLMAP's (centres at +0.5). Without the quarter, one corner
found in a frame and in the frame decoded at half size differed by 0.25 px. Descriptors are
RootSIFT scaled to uint8 as COLMAP's extractor stores them (L1-normalised, square root, x 512).
"""

from __future__ import annotations

from collections import deque
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import cv2
import numpy as np

COLMAP_OFFSET_PX = 0.25  # COLMAP's pixel centres (+0.5) less OpenCV SIFT's quarter (see above)


def sift_features(image_gray: np.ndarray, max_features: int) -> tuple[np.ndarray, np.ndarray]:
    """(K, 4) float32 COLMAP keypoints (x, y in COLMAP pixels, scale, orientation in radians) and
    (K, 128) uint8 RootSIFT descriptors of a grayscale frame."""
    sift = cv2.SIFT_create(nfeatures=max_features)
    keypoints, desc = sift.detectAndCompute(image_gray, None)
    if not keypoints:
        return np.zeros((0, 4), np.float32), np.zeros((0, 128), np.uint8)
    kp = np.array([(k.pt[0], k.pt[1], k.size, k.angle) for k in keypoints], np.float64)
    out = np.empty((len(kp), 4), np.float32)
    out[:, :2] = kp[:, :2] + COLMAP_OFFSET_PX
    out[:, 2] = kp[:, 2] / 2
    out[:, 3] = np.deg2rad(kp[:, 3])
    desc = desc / np.maximum(desc.sum(axis=1, keepdims=True), 1e-12)
    return out, np.clip(np.round(512 * np.sqrt(desc)), 0, 255).astype(np.uint8)


def extract_into(pycolmap, database: Path, image_dir: Path, names: list[str], reader_options, *,
                 max_features: int, threads: int) -> None:
    """Add ``names`` (frames under ``image_dir``) and their OpenCV SIFT to ``database`` (an
    existing COLMAP database), one camera for all as ``CameraMode.SINGLE`` gives. Frames are
    extracted ``threads`` at a time (OpenCV releases the GIL)."""
    pycolmap.import_images(database, image_dir, pycolmap.CameraMode.SINGLE, image_names=names,
                           options=reader_options)
    with pycolmap.Database.open(database) as db:
        ids = {im.name: im.image_id for im in db.read_all_images()}
    kept = [n for n in names if n in ids]  # COLMAP skips frames it cannot read; so do we

    def one(name: str):
        image = cv2.imread(str(image_dir / name), cv2.IMREAD_GRAYSCALE)
        return sift_features(image, max_features) if image is not None else None

    def write(db, name: str, features) -> None:
        if features is not None:
            keypoints, descriptors = features
            db.write_keypoints(ids[name], keypoints)
            db.write_descriptors(ids[name], pycolmap.FeatureDescriptors(
                pycolmap.FeatureExtractorType.SIFT, descriptors))

    # A few frames in flight at a time: memory stays bounded whatever the journey's length.
    with ThreadPoolExecutor(max_workers=max(1, threads)) as pool, \
            pycolmap.Database.open(database) as db:
        pending: deque = deque()
        for name in kept:
            pending.append((name, pool.submit(one, name)))
            if len(pending) > 2 * threads:
                done, future = pending.popleft()
                write(db, done, future.result())
        for done, future in pending:
            write(db, done, future.result())
