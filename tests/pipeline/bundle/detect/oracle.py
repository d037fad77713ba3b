"""An "oracle" ONNX detector for one rendered journey, so that a bundle without detections.csv can
be mapped end to end from a model's boxes that differ frame by frame.

``stamp_bundle`` drops detections.csv (optionally re-encoding the frames as JPEG) and writes each
frame's index into its pixels: a strip of ``BITS`` blocks of ``BLOCK`` x ``BLOCK`` original pixels
in the top-left corner, each one of two colours of equal luminance (Rec. 601 and Rec. 709 alike),
on a grey of that luminance. Feature detectors, which see the grey image, find a flat patch there
and nothing that moves with the bits (black and white blocks would be corners fixed in the image
in every frame); the chroma survives JPEG (4:2:0) and the letterbox resize to 640 (a block is then
16 px; the model reads its central 8 x 8).

``oracle_model`` builds the ONNX model (onnx.helper) that reads the index back from its input
(Slice, ReduceMean, B - R, Greater, Cast, Mul by bit weights, ReduceSum) and Gathers that frame's
true boxes, the original bundle's detections.csv, from a table: output ``[1, K, 6]`` (NMS built in:
x1, y1, x2, y2 in letterboxed input pixels, score, class), rows past a frame's boxes scoring 0.
"""

from __future__ import annotations

import csv
import io
import zipfile
from pathlib import Path

import cv2
import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper

from tests.pipeline.bundle.detect.models import SIZE, letterbox_geometry, to_input

BITS = 10  # frame indices 0 ... 1023
BLOCK = 32  # original pixels
MARGIN = 4
# x1, y1, x2, y2 (exclusive) of the strip in original pixels: no sign box may touch it.
STRIP = (0, 0, 2 * MARGIN + BITS * BLOCK, 2 * MARGIN + BLOCK)
# BGR of a 1 and a 0 bit, and the grey around them: luminance 128 in both conventions, B - R
# +144 and -144.
ONE, ZERO, GREY = (228, 131, 84), (28, 125, 172), (128, 128, 128)


def _block(k: int) -> tuple[int, int, int, int]:
    """x1, y1, x2, y2 (exclusive) of bit k's block in original pixels."""
    x = MARGIN + k * BLOCK
    return x, MARGIN, x + BLOCK, MARGIN + BLOCK


def stamp(bgr: np.ndarray, index: int) -> np.ndarray:
    """``bgr`` with ``index`` written into its top-left strip (a copy)."""
    if not 0 <= index < 2 ** BITS:
        raise ValueError(f"frame index {index} does not fit in {BITS} bits")
    out = bgr.copy()
    x1, y1, x2, y2 = STRIP
    out[y1:y2, x1:x2] = GREY
    for k in range(BITS):
        bx1, by1, bx2, by2 = _block(k)
        out[by1:by2, bx1:bx2] = ONE if index >> k & 1 else ZERO
    return out


def _frame_names(names: list[str]) -> list[str]:
    """The bundle's frame entries in frame order (by stem, as ``bundle.read`` orders them)."""
    frames = [n for n in names if n.startswith("frames/") and n.count("/") == 1
              and n.rpartition(".")[2] in ("jpg", "jpeg", "png")]
    return sorted(frames, key=lambda n: Path(n).stem)


def stamp_bundle(src: Path, dst: Path, jpeg_quality: int | None = None) -> Path:
    """``src`` with every frame stamped with its index and no detections.csv, written to ``dst``;
    the frames keep their format, or with ``jpeg_quality`` become JPEGs (``<stem>.jpg``)."""
    with zipfile.ZipFile(src) as zin, zipfile.ZipFile(dst, "w", zipfile.ZIP_STORED) as zout:
        index = {name: i for i, name in enumerate(_frame_names(zin.namelist()))}
        for item in zin.infolist():
            name = item.filename
            if name == "detections.csv":
                continue
            data = zin.read(name)
            if name in index:
                bgr = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
                stem, _, ext = name.rpartition(".")
                if jpeg_quality is not None:
                    name, ext = f"{stem}.jpg", "jpg"
                params = [] if ext == "png" else [cv2.IMWRITE_JPEG_QUALITY, jpeg_quality or 95]
                ok, encoded = cv2.imencode("." + ext, stamp(bgr, index[item.filename]), params)
                assert ok, name
                data = encoded.tobytes()
            zout.writestr(zipfile.ZipInfo(name, item.date_time), data)
    return dst


def true_boxes(bundle: Path) -> tuple[list[str], list[list[tuple]], tuple[int, int]]:
    """The classes (sorted), each frame's (x1, y1, x2, y2, score, class index) rows from the
    bundle's detections.csv (original OpenCV pixels; frames in frame order) and the frames'
    (width, height)."""
    with zipfile.ZipFile(bundle) as z:
        frames = _frame_names(z.namelist())
        first = cv2.imdecode(np.frombuffer(z.read(frames[0]), np.uint8), cv2.IMREAD_COLOR)
        rows = list(csv.DictReader(io.StringIO(z.read("detections.csv").decode())))
    classes = sorted({r["class"] for r in rows})
    index = {Path(n).stem: i for i, n in enumerate(frames)}
    per_frame: list[list[tuple]] = [[] for _ in frames]
    for r in rows:
        score = float(r["score"]) if r.get("score") else 1.0
        per_frame[index[r["frame"]]].append((float(r["x1"]), float(r["y1"]), float(r["x2"]),
                                             float(r["y2"]), score, classes.index(r["class"])))
    return classes, per_frame, (first.shape[1], first.shape[0])


def _touches_strip(box) -> bool:
    x1, y1, x2, y2 = STRIP
    return box[0] < x2 + 0.5 and box[1] < y2 + 0.5 and box[2] > x1 - 0.5 and box[3] > y1 - 0.5


def _sample(k: int, geometry) -> tuple[list[int], list[int]]:
    """Input-pixel starts and ends (rows, columns) of the centre of bit k's block."""
    scale, left, top = geometry
    bx1, by1, bx2, by2 = _block(k)
    cx, cy = ((bx1 + bx2) / 2) * scale + left, ((by1 + by2) / 2) * scale + top
    half = max(1, int(BLOCK * scale / 4))
    return ([int(round(cy)) - half, int(round(cx)) - half],
            [int(round(cy)) + half, int(round(cx)) + half])


def oracle_model(path: Path, bundle: Path, size: int = SIZE) -> Path:
    """The oracle detector of ``bundle`` (the original, with detections.csv), for frames stamped
    by ``stamp_bundle``; ValueError when a box touches the strip or there are too many frames."""
    classes, per_frame, (width, height) = true_boxes(bundle)
    if len(per_frame) > 2 ** BITS:
        raise ValueError(f"{len(per_frame)} frames do not fit in {BITS} bits")
    touching = [b for boxes in per_frame for b in boxes if _touches_strip(b)]
    if touching:
        raise ValueError(f"boxes touch the index strip {STRIP}: {touching[:3]}")
    geometry = letterbox_geometry(width, height, size)
    k_max = max(1, max(len(boxes) for boxes in per_frame))
    # Every code has rows (those of no frame are all 0), so a misread index cannot fail Gather.
    table = np.zeros((2 ** BITS, k_max, 6), np.float32)
    for i, boxes in enumerate(per_frame):
        for j, (x1, y1, x2, y2, score, cls) in enumerate(boxes):
            table[i, j] = [*to_input((x1, y1, x2, y2), geometry), score, cls]
    nodes, inits, means = [], [], []
    for k in range(BITS):
        starts, ends = _sample(k, geometry)
        inits += [numpy_helper.from_array(np.array(starts, np.int64), f"starts{k}"),
                  numpy_helper.from_array(np.array(ends, np.int64), f"ends{k}")]
        nodes += [helper.make_node("Slice", ["images", f"starts{k}", f"ends{k}", "hw"],
                                   [f"block{k}"]),
                  helper.make_node("ReduceMean", [f"block{k}"], [f"mean{k}"], axes=[2, 3],
                                   keepdims=0)]
        means.append(f"mean{k}")
    nodes += [
        helper.make_node("Concat", means, ["means"], axis=0),  # [BITS, 3] RGB
        helper.make_node("Mul", ["means", "b_minus_r"], ["weighted"]),
        helper.make_node("ReduceSum", ["weighted", "axis1"], ["chroma"], keepdims=0),
        helper.make_node("Greater", ["chroma", "zero"], ["is_one"]),
        helper.make_node("Cast", ["is_one"], ["bits"], to=TensorProto.FLOAT),
        helper.make_node("Mul", ["bits", "bit_values"], ["values"]),
        helper.make_node("ReduceSum", ["values", "axis0"], ["index_f"], keepdims=1),
        helper.make_node("Cast", ["index_f"], ["index"], to=TensorProto.INT64),
        helper.make_node("Gather", ["table", "index"], ["output0"], axis=0),
    ]
    inits += [
        numpy_helper.from_array(np.array([2, 3], np.int64), "hw"),
        numpy_helper.from_array(np.array([-1.0, 0.0, 1.0], np.float32), "b_minus_r"),
        numpy_helper.from_array(np.array([1], np.int64), "axis1"),
        numpy_helper.from_array(np.array([0], np.int64), "axis0"),
        numpy_helper.from_array(np.array(0.0, np.float32), "zero"),
        numpy_helper.from_array(2.0 ** np.arange(BITS, dtype=np.float32), "bit_values"),
        numpy_helper.from_array(table, "table"),
    ]
    graph = helper.make_graph(
        nodes, "oracle",
        [helper.make_tensor_value_info("images", TensorProto.FLOAT, [1, 3, size, size])],
        [helper.make_tensor_value_info("output0", TensorProto.FLOAT, [1, k_max, 6])],
        initializer=inits)
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8
    helper.set_model_props(model, {"names": repr(dict(enumerate(classes)))})
    onnx.checker.check_model(model)
    onnx.save(model, str(path))
    return path
