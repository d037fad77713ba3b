"""The journey page of a video journey: its GPS track comes from the log without decoding the
video, and an observation's crop is that frame of the video."""

from __future__ import annotations

import hashlib

import av
import cv2
import numpy as np

from app.service.admin import media
from app.service.storage import LocalBundleStore
from tests.pipeline.video import bundles


def _stored(tmp_path) -> tuple[LocalBundleStore, str]:
    data = bundles.valid()
    sha256 = hashlib.sha256(data).hexdigest()
    incoming = tmp_path / "incoming.zip"
    incoming.write_bytes(data)
    store = LocalBundleStore(tmp_path / "data")
    store.put(sha256, incoming)
    return store, sha256


def test_a_video_journeys_track_is_its_gps_log(tmp_path):
    store, sha256 = _stored(tmp_path)
    track = media.gps_track(tmp_path / "data", store, sha256)
    assert len(track) == 11  # the 1 Hz log's 11 fixes, not one per frame
    assert track[0] == [48.0, 11.0]


def test_a_video_journeys_crop_is_the_frame_of_the_video(tmp_path):
    store, sha256 = _stored(tmp_path)
    png = media.crop_png(tmp_path / "data", store, sha256, "000025", None)
    with av.open(str(next((tmp_path / "data" / "cache" / "admin" / "videos").iterdir()))) as c:
        frame_25 = [f.to_ndarray(format="bgr24") for f in c.decode(video=0)][25]
    image = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)
    assert image.shape == frame_25.shape
    assert np.abs(image.astype(int) - frame_25.astype(int)).mean() < 1.0  # PNG: lossless
    assert media.crop_png(tmp_path / "data", store, sha256, "000999", None) is None
