"""Hostile journey bundles found by probing the service (issue 13), built quickly in memory.

Each builder returns the zip's bytes and is cached, so a test session builds each once. They are
small uploads that used to cost the API seconds to minutes and gigabytes;
``tests/service/uploads/test_bad_input_corpus.py`` holds what the service must answer to each, and
``bench/service/hostile_uploads.py`` measures what each costs the API process.
"""

from __future__ import annotations

import functools
import io
import struct
import zlib

import numpy as np
from PIL import Image

from tests.utils import bundle_factory as bf

PAD_BYTES = 250 * 2**20


def _gps_without(frame: str, n_frames: int = 5) -> bytes:
    """A gps.csv lacking the row of ``frame`` (bad GPS: "no GPS timestamp for frame ...")."""
    return bf.csv_bytes(bf.GPS_HEADER, [r for r in bf.gps_rows(n_frames) if r[0] != frame])


@functools.cache
def detection_rows(n_rows: int) -> bytes:
    """``n_rows`` well-formed detection rows (each its own track, at most 200 per frame) on a valid
    bundle of 5000 tiny frames."""
    n_frames = 5000
    ids = bf.frame_ids(n_frames)
    png = bf.image_bytes(width=8, height=8)
    lines = [",".join(bf.DETECTIONS_HEADER)]
    lines += [f"{ids[k % n_frames]},t{k},stop,1,1,5,5," for k in range(n_rows)]
    files = {"manifest.json": bf.manifest_bytes(), **{f"frames/{f}.png": png for f in ids},
             "gps.csv": bf.csv_bytes(bf.GPS_HEADER, bf.gps_rows(n_frames, fix_rows=False)),
             "detections.csv": "\n".join(lines).encode()}
    return bf.zip_bytes(files)


def million_detection_rows() -> bytes:
    return detection_rows(1_000_000)


def unlabelled_boxes(n_frames: int, boxes_per_frame: int, seed: int = 0) -> dict[str, bytes]:
    """A valid 5-frame bundle whose first ``n_frames`` frames hold that many unlabelled boxes of
    one class, all inside the 64x48 image (so every pair is a candidate for association)."""
    rng = np.random.default_rng(seed)
    rows = []
    for f in bf.frame_ids()[:n_frames]:
        x1, y1 = rng.uniform(0, 50, boxes_per_frame), rng.uniform(0, 35, boxes_per_frame)
        w, h = rng.uniform(3, 12, (2, boxes_per_frame))
        rows += [(f, "", "stop", f"{a:.2f}", f"{b:.2f}", f"{a + c:.2f}", f"{b + d:.2f}", "")
                 for a, b, c, d in zip(x1, y1, w, h)]
    return {**bf.valid_files(detections=False),
            "detections.csv": bf.csv_bytes(bf.DETECTIONS_HEADER, rows)}


@functools.cache
def thousand_boxes_per_frame() -> bytes:
    return bf.zip_bytes(unlabelled_boxes(3, 1000))


def _raw_zip(members: list[tuple[str, bytes, int, int, int]]) -> bytes:
    """A zip from (name, raw deflate stream, crc32, compressed size, uncompressed size) members:
    identical huge members are compressed once and written many times."""
    out, central = io.BytesIO(), []
    for name, raw, crc, csize, usize in members:
        offset = out.tell()
        encoded = name.encode()
        out.write(struct.pack("<IHHHHHIIIHH", 0x04034B50, 20, 0, 8, 0, 0x21, crc, csize, usize,
                              len(encoded), 0) + encoded + raw)
        central.append(struct.pack("<IHHHHHHIIIHHHHHII", 0x02014B50, 20, 20, 0, 8, 0, 0x21, crc,
                                   csize, usize, len(encoded), 0, 0, 0, 0, 0, offset) + encoded)
    start = out.tell()
    out.write(b"".join(central))
    out.write(struct.pack("<IHHHHIIH", 0x06054B50, 0, 0, len(members), len(members),
                          out.tell() - start, start, 0))
    return out.getvalue()


def _deflated(data_parts: list[bytes], repeat_last: int = 1) -> tuple[bytes, int, int]:
    """(raw deflate, crc32, size) of the concatenation, the last part repeated ``repeat_last``
    times (fed in pieces: the padding is never held whole)."""
    comp = zlib.compressobj(6, zlib.DEFLATED, -15)
    raw, crc, size = [], 0, 0
    for part in [*data_parts[:-1], *[data_parts[-1]] * repeat_last]:
        raw.append(comp.compress(part))
        crc, size = zlib.crc32(part, crc), size + len(part)
    raw.append(comp.flush())
    return b"".join(raw), crc, size


def _member(name: str, data: bytes) -> tuple[str, bytes, int, int, int]:
    raw, crc, size = _deflated([data])
    return name, raw, crc, len(raw), size


@functools.cache
def _padded_frame(pad_bytes: int) -> tuple[bytes, int, int]:
    chunk = 2**20
    return _deflated([bf.image_bytes(), bytes(chunk)], repeat_last=pad_bytes // chunk)


def padded_frames(n_frames: int = 8, pad_bytes: int = PAD_BYTES, *,
                  unreadable_last: bool = False) -> bytes:
    """``n_frames`` valid PNGs each followed by ``pad_bytes`` of zeros (decoders ignore trailing
    bytes), with bad GPS (a frame's row missing); optionally the last frame is garbage."""
    raw, crc, size = _padded_frame(pad_bytes)
    ids = bf.frame_ids(n_frames)
    members = [_member("manifest.json", bf.manifest_bytes()),
               _member("gps.csv", _gps_without(ids[1], n_frames))]
    members += [(f"frames/{f}.png", raw, crc, len(raw), size) for f in ids]
    if unreadable_last:
        members[-1] = _member(f"frames/{ids[-1]}.png", b"garbage" * 1000)
    return _raw_zip(members)


def _png_header_claiming(width: int, height: int) -> bytes:
    """A PNG whose IHDR claims ``width`` x ``height`` (the pixel data is a few bytes)."""
    def chunk(kind: bytes, body: bytes) -> bytes:
        crc = struct.pack(">I", zlib.crc32(kind + body))
        return struct.pack(">I", len(body)) + kind + body + crc
    ihdr = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(bytes(64)))
            + chunk(b"IEND", b""))


def _jpeg_claiming(width: int, height: int) -> bytes:
    """A real small JPEG whose SOF0 header is rewritten to claim ``width`` x ``height``."""
    data = bytearray(bf.image_bytes("jpg"))
    sof = data.index(b"\xff\xc0")
    struct.pack_into(">HH", data, sof + 5, height, width)
    return bytes(data)


def png_header_claiming_20000() -> bytes:
    files = bf.valid_files()
    return bf.zip_bytes({**files, "frames/000000.png": _png_header_claiming(20000, 20000)})


def jpeg_header_claiming_65000() -> bytes:
    files = bf.valid_files(image_format="jpg")
    return bf.zip_bytes({**files, "frames/000000.jpg": _jpeg_claiming(65000, 65000)})


@functools.cache
def real_8192_frames() -> bytes:
    """Three real (black) 8192 x 8192 PNG frames: a zip of a few kB, 200 MB of pixels each."""
    out = io.BytesIO()
    Image.fromarray(np.zeros((8192, 8192), np.uint8)).save(out, "PNG")
    files = bf.valid_files(3, detections=False)
    files.update({f"frames/{f}.png": out.getvalue() for f in bf.frame_ids(3)})
    return bf.zip_bytes(files)


@functools.cache
def frame_lying_about_its_size() -> bytes:
    """frames/000002.png declares 1000 bytes but inflates to 250 MiB."""
    raw, crc, size = _padded_frame(PAD_BYTES)
    files = {**bf.valid_files()}
    members = [_member(n, d) for n, d in files.items() if n != "frames/000002.png"]
    members.append(("frames/000002.png", raw, crc, len(raw), 1000))
    return _raw_zip(members)
