"""Tiny ONNX detectors whose output is a constant tensor (the pixels enter only multiplied by
zero), and the boxes they stand for, in original OpenCV pixels of a WIDTH x HEIGHT image."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper

SIZE = 640
WIDTH, HEIGHT = 1242, 375


def letterbox_geometry(width: int, height: int, size: int = SIZE) -> tuple[float, int, int]:
    """Scale, left and top padding of a width x height image letterboxed into size x size
    (ultralytics' rounding)."""
    scale = min(size / height, size / width)
    left = int(round((size - round(width * scale)) / 2 - 0.1))
    top = int(round((size - round(height * scale)) / 2 - 0.1))
    return scale, left, top


# Letterbox of 1242x375 into 640.
SCALE, LEFT, TOP = letterbox_geometry(WIDTH, HEIGHT)

# (x1, y1, x2, y2 in original OpenCV pixels, score, class index)
STOP = ((100.0, 50.0, 160.0, 110.0), 0.9, 0)
STOP_OVERLAP = ((104.0, 52.0, 162.0, 112.0), 0.8, 0)  # IoU ~0.8 with STOP: NMS drops it
YIELD = ((600.0, 100.0, 640.0, 140.0), 0.7, 1)
YIELD_WEAK = ((900.0, 200.0, 950.0, 250.0), 0.1, 1)  # under score_min
BOXES = (STOP, STOP_OVERLAP, YIELD, YIELD_WEAK)
NC = 2


def to_input(box, geometry: tuple[float, int, int] = (SCALE, LEFT, TOP)) -> np.ndarray:
    """Original OpenCV pixels -> letterboxed input pixels (edges at integers); ``geometry`` is
    ``letterbox_geometry``'s."""
    scale, left, top = geometry
    x1, y1, x2, y2 = box
    return np.array([(x1 + 0.5) * scale + left, (y1 + 0.5) * scale + top,
                     (x2 + 0.5) * scale + left, (y2 + 0.5) * scale + top])


def _cxcywh(box) -> np.ndarray:
    x1, y1, x2, y2 = to_input(box)
    return np.array([(x1 + x2) / 2, (y1 + y2) / 2, x2 - x1, y2 - y1])


def output(layout: str, boxes=BOXES) -> np.ndarray:
    rows = []
    for box, score, cls in boxes:
        scores = np.zeros(NC)
        scores[cls] = score
        if layout == "v8":
            rows.append(np.concatenate([_cxcywh(box), scores]))
        elif layout == "v5":
            # objectness 0.5 and class score 2 x: the product is the score
            rows.append(np.concatenate([_cxcywh(box), [0.5], 2 * scores]))
        else:
            rows.append(np.concatenate([to_input(box), [score, cls]]))
    out = np.array(rows, dtype=np.float32)[None]
    return out.transpose(0, 2, 1).copy() if layout == "v8" else out


def constant_model(path: Path, value: np.ndarray, names: str | None = None,
                   size: int = SIZE) -> Path:
    """An ONNX model [1, 3, size, size] -> ``value`` (plus 0 x the pixels' mean)."""
    nodes = [
        helper.make_node("ReduceMean", ["images"], ["mean"], keepdims=0),
        helper.make_node("Mul", ["mean", "zero"], ["nothing"]),
        helper.make_node("Add", ["boxes", "nothing"], ["output0"]),
    ]
    graph = helper.make_graph(
        nodes, "constant",
        [helper.make_tensor_value_info("images", TensorProto.FLOAT, [1, 3, size, size])],
        [helper.make_tensor_value_info("output0", TensorProto.FLOAT, list(value.shape))],
        initializer=[numpy_helper.from_array(np.asarray(value, np.float32), "boxes"),
                     numpy_helper.from_array(np.array(0.0, np.float32), "zero")])
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8
    if names is not None:
        helper.set_model_props(model, {"names": names})
    onnx.checker.check_model(model)
    onnx.save(model, str(path))
    return path
