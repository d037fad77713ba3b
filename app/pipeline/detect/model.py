"""Loading an ONNX sign detector and running it on one image.

Supported outputs (the first output of the model, batch 1):

* YOLOv8/v11 ``[1, 4 + nc, N]``: cx, cy, w, h, then one score per class;
* YOLOv5/v7 ``[1, N, 5 + nc]``: cx, cy, w, h, objectness, then class scores (score = obj * cls);
* NMS built in ``[1, N, 6]``: x1, y1, x2, y2, score, class.

The layout is told from the shape; a single-class YOLOv5 export is ``[1, N, 6]`` too and is read
as NMS built in unless ``DetectorConfig.layout`` says "v5".

Boxes are in the letterboxed input's pixels (ultralytics: edges at integers); they are mapped back
to the original image and shifted by -0.5 to the OpenCV convention of ``app.pipeline.types``.
"""

from __future__ import annotations

import ast
import hashlib
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import cv2
import numpy as np
from pydantic import BaseModel, Field

PAD_VALUE = 114


class DetectorError(Exception):
    """The detector cannot be used; ``str(exc)`` says why in one line."""


class DetectorConfig(BaseModel):
    """``SIGNMAP_DETECTOR__<NAME>``: the ONNX model run on bundles without detections.csv."""

    model: Path | None = Field(None, description="ONNX detector; unset = no detector")
    labels: list[str] | None = Field(
        None, description="class names by index; default: the model's metadata `names`, else "
                          "class<i>")
    score_min: float = Field(0.25, ge=0.0, le=1.0, description="boxes scoring less are dropped")
    input_size: int | None = Field(None, gt=0, description="square input side; default: the "
                                                           "model's own")
    classes: list[str] | None = Field(None, description="keep only these classes; unset = all")
    iou_nms: float = Field(0.45, gt=0.0, le=1.0, description="per-class NMS IoU threshold")
    layout: Literal["auto", "v8", "v5", "nms"] = Field(
        "auto", description="output layout; auto: from its shape ([1, N, 6] is NMS built in; a "
                            "single-class YOLOv5 export needs v5)")


@dataclass(frozen=True)
class Box:
    """One detected box in the original image, OpenCV pixels."""

    x1: float
    y1: float
    x2: float
    y2: float
    score: float
    cls: str


def _one_line(exc: BaseException) -> str:
    text = str(exc).strip()
    return text.splitlines()[0][:300] if text else type(exc).__name__


def parse_names(text: str) -> list[str] | None:
    """Ultralytics' ``names`` metadata (``"{0: 'stop', 1: 'yield'}"`` or a list) as a list by
    index; None when it cannot be read."""
    try:
        value = ast.literal_eval(text)
    except (ValueError, SyntaxError, MemoryError, RecursionError):
        return None
    if isinstance(value, dict):
        try:
            index = {int(k): str(v) for k, v in value.items()}
        except (TypeError, ValueError):
            return None
        return [index.get(i, f"class{i}") for i in range(max(index, default=-1) + 1)]
    if isinstance(value, (list, tuple)):
        return [str(v) for v in value]
    return None


def letterbox(bgr: np.ndarray, size: int) -> tuple[np.ndarray, float, int, int]:
    """``bgr`` resized to fit ``size`` x ``size`` keeping its aspect, padded with 114 and centred
    (ultralytics' rounding); returns the image, the scale and the left and top padding."""
    h, w = bgr.shape[:2]
    r = min(size / h, size / w)
    new_w, new_h = int(round(w * r)), int(round(h * r))
    dw, dh = (size - new_w) / 2, (size - new_h) / 2
    top, bottom = int(round(dh - 0.1)), int(round(dh + 0.1))
    left, right = int(round(dw - 0.1)), int(round(dw + 0.1))
    img = bgr if (new_w, new_h) == (w, h) else cv2.resize(bgr, (new_w, new_h),
                                                          interpolation=cv2.INTER_LINEAR)
    img = cv2.copyMakeBorder(img, top, bottom, left, right, cv2.BORDER_CONSTANT,
                             value=(PAD_VALUE,) * 3)
    return img, r, left, top


def _layout(shape: tuple, forced: str = "auto") -> str | None:
    """"v8", "v5" or "nms" for an output shape (ints, or None / names for dynamic axes): the
    ``forced`` one if the shape can be of it, else None; with "auto" the one the shape says."""
    if len(shape) != 3 or shape[0] not in (1, None) and not isinstance(shape[0], str):
        return None
    a, b = shape[1], shape[2]
    if forced != "auto":
        fits = {"nms": b == 6, "v5": isinstance(b, int) and b > 5,
                "v8": isinstance(a, int) and a > 4}
        return forced if fits[forced] else None
    if b == 6:
        return "nms"
    if isinstance(b, int) and b > 5 and not (isinstance(a, int) and a > 4 and a < b):
        return "v5"
    if isinstance(a, int) and a > 4:
        return "v8"
    return None


_SHAPES = {"v8": "[1, 4+nc, N] (YOLOv8/v11, layout v8)",
           "v5": "[1, N, 5+nc] (YOLOv5/v7, layout v5)",
           "nms": "[1, N, 6] (NMS built in, layout nms)"}
_SHAPES["auto"] = ", ".join(_SHAPES.values())


class Detector:
    """An ONNX model ready to run (build it with ``load_detector``)."""

    def __init__(self, session, config: DetectorConfig, path: Path, input_size: int,
                 labels: list[str] | None, sha256: str):
        self.session = session
        self.config = config
        self.path = path
        self.input_size = input_size
        self.labels = labels
        self.sha256 = sha256
        self.input_name = session.get_inputs()[0].name

    def label(self, index: int) -> str:
        if self.labels is not None and 0 <= index < len(self.labels):
            return self.labels[index]
        return f"class{index}"

    def prepare(self, bgr: np.ndarray) -> tuple[np.ndarray, float, int, int]:
        """The model's input for ``bgr`` (letterboxed, RGB, 0-1, [1, 3, size, size] float32) and
        the letterbox's scale, left and top padding."""
        if bgr.ndim == 2:
            bgr = cv2.cvtColor(bgr, cv2.COLOR_GRAY2BGR)
        img, r, left, top = letterbox(bgr, self.input_size)
        blob = np.ascontiguousarray(img[:, :, ::-1].transpose(2, 0, 1)[None], dtype=np.float32)
        blob /= 255.0
        return blob, r, left, top

    def infer(self, blob: np.ndarray) -> np.ndarray:
        """The model's first output for ``blob``."""
        return np.asarray(self.session.run(None, {self.input_name: blob})[0])

    def _raw(self, bgr: np.ndarray) -> tuple[np.ndarray, float, int, int]:
        blob, r, left, top = self.prepare(bgr)
        return self.infer(blob), r, left, top

    def decode(self, out: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(N, 4) x1 y1 x2 y2 in input pixels, (N,) scores, (N,) class indices."""
        layout = _layout(tuple(out.shape), self.config.layout)
        if layout is None or out.shape[0] != 1:
            raise DetectorError(f"model output of shape {list(out.shape)} is none of "
                                f"{_SHAPES[self.config.layout]}")
        out = out[0].astype(np.float64)
        if layout == "nms":
            return out[:, :4], out[:, 4], out[:, 5].round().astype(int)
        if layout == "v8":
            out = out.T
            cxcywh, scores = out[:, :4], out[:, 4:]
        else:
            cxcywh, scores = out[:, :4], out[:, 5:] * out[:, 4:5]
        cls = scores.argmax(axis=1) if scores.shape[1] else np.zeros(len(out), int)
        score = scores[np.arange(len(out)), cls] if scores.shape[1] else np.zeros(len(out))
        cx, cy, w, h = cxcywh.T
        boxes = np.column_stack([cx - w / 2, cy - h / 2, cx + w / 2, cy + h / 2])
        return boxes, score, cls

    def detect(self, bgr: np.ndarray) -> list[Box]:
        """Boxes in ``bgr`` (an OpenCV image), in its OpenCV pixels, best first per class."""
        out, r, left, top = self._raw(bgr)
        return self.boxes(out, r, left, top, bgr.shape[1], bgr.shape[0])

    def boxes(self, out: np.ndarray, r: float, left: int, top: int, width: int,
              height: int) -> list[Box]:
        """The model's output ``out`` for a ``width`` x ``height`` image letterboxed with scale
        ``r`` and padding ``left``, ``top``: its boxes after the score, class and NMS filters, in
        the image's OpenCV pixels."""
        boxes, scores, cls = self.decode(out)
        keep = np.isfinite(boxes).all(axis=1) & (scores >= self.config.score_min)
        boxes, scores, cls = boxes[keep], scores[keep], cls[keep]
        # Named after the score filter: a YOLOv8 output has 8400 rows at 640 px.
        names = np.array([self.label(int(c)) for c in cls], dtype=object)
        if self.config.classes is not None:
            wanted = np.isin(names, list(self.config.classes))
            boxes, scores, names = boxes[wanted], scores[wanted], names[wanted]
        # Input pixels (edges at integers) -> original pixels -> OpenCV centres.
        boxes = (boxes - [left, top, left, top]) / r - 0.5
        boxes[:, [0, 2]] = boxes[:, [0, 2]].clip(-0.5, width - 0.5)
        boxes[:, [1, 3]] = boxes[:, [1, 3]].clip(-0.5, height - 0.5)
        good = (boxes[:, 2] > boxes[:, 0]) & (boxes[:, 3] > boxes[:, 1])
        boxes, scores, names = boxes[good], scores[good], names[good]
        found: list[Box] = []
        for name in dict.fromkeys(names):
            idx = np.flatnonzero(names == name)
            xywh = [[float(b[0]), float(b[1]), float(b[2] - b[0]), float(b[3] - b[1])]
                    for b in boxes[idx]]
            kept = cv2.dnn.NMSBoxes(xywh, [float(s) for s in scores[idx]],
                                    float(self.config.score_min), float(self.config.iou_nms))
            for k in sorted(np.asarray(kept, dtype=int).reshape(-1), key=lambda k: -scores[idx[k]]):
                b = boxes[idx[k]]
                found.append(Box(float(b[0]), float(b[1]), float(b[2]), float(b[3]),
                                 float(scores[idx[k]]), str(name)))
        return found


def _sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as fp:
        for chunk in iter(lambda: fp.read(1 << 20), b""):
            digest.update(chunk)
    return digest.hexdigest()


def load_detector(config: DetectorConfig) -> Detector:
    """The detector ``config`` names; DetectorError (one line) when it cannot be loaded or its
    output is of no supported layout."""
    # Called once per journey (apply_detector): 0.1-0.25 s for a YOLOv8n-sized model (signmap bench
    # detector), small beside the journey's frames; a worker could keep one if that changes.
    if config.model is None:
        raise DetectorError("no detector model configured")
    path = Path(config.model)
    if not path.is_file():
        raise DetectorError(f"detector model {path} does not exist")
    try:
        import onnxruntime as ort
    except ImportError as exc:  # pragma: no cover - a dependency
        raise DetectorError(f"onnxruntime is not installed: {_one_line(exc)}") from None
    options = ort.SessionOptions()
    options.intra_op_num_threads = 2
    options.inter_op_num_threads = 1
    options.log_severity_level = 3
    try:
        session = ort.InferenceSession(str(path), sess_options=options,
                                       providers=["CPUExecutionProvider"])
    except Exception as exc:
        raise DetectorError(f"detector model {path} cannot be loaded: {_one_line(exc)}") from None
    inputs = session.get_inputs()
    if len(inputs) != 1 or len(inputs[0].shape) != 4:
        raise DetectorError(f"detector model {path} must take one image input [1, 3, H, W], "
                            f"not {[list(i.shape) for i in inputs]}")
    in_shape = inputs[0].shape
    own = [d for d in in_shape[2:] if isinstance(d, int)]
    size = config.input_size or (max(own) if own else None)
    if size is None:
        raise DetectorError(f"detector model {path} has a dynamic input size: set "
                            "SIGNMAP_DETECTOR__INPUT_SIZE")
    if own and len(own) == 2 and own[0] != own[1]:
        raise DetectorError(f"detector model {path} takes a non-square input {in_shape[2:]}")
    if own and config.input_size and config.input_size not in own:
        raise DetectorError(f"detector model {path} takes {own[0]} px inputs, not "
                            f"input_size {config.input_size}")
    labels = list(config.labels) if config.labels else None
    if labels is None:
        names = session.get_modelmeta().custom_metadata_map.get("names")
        labels = parse_names(names) if names else None
    detector = Detector(session, config, path, int(size), labels, _sha256(path))
    # Check the output layout once, on a blank image: a wrong model fails here, not per frame.
    try:
        out, *_ = detector._raw(np.full((size, size, 3), PAD_VALUE, np.uint8))
    except Exception as exc:
        raise DetectorError(f"detector model {path} fails to run: {_one_line(exc)}") from None
    if _layout(tuple(out.shape), config.layout) is None or out.shape[0] != 1:
        raise DetectorError(f"detector model {path} outputs shape {list(out.shape)}, none of "
                            f"{_SHAPES[config.layout]}")
    return detector
