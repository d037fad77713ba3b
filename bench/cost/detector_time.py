"""``signmap bench detector``: the sign detector's time per frame at 640 px on 2 threads.

No trained model ships, so the bench builds one of a realistic size: five stride-2 3x3 convolution
stages (24 to 384 channels, SiLU, a stride-1 convolution after each but the first) and a YOLOv8-like
head of 1x1 convolutions on the 80, 40 and 20 px maps, output ``[1, 4 + nc, 8400]`` (boxes and
class scores through a sigmoid), random weights: 6.5 GFLOPs, 2.7 M parameters (YOLOv8n: 8.7
GFLOPs, 3.2 M). Its class scores are shifted so that about ``CANDIDATES`` boxes of the first frame
pass ``score_min``, as a trained model's do on a street, for NMS to have a realistic amount of
work.

It runs through the worker's own path (``load_detector``, ``detect_journey``) on N JPEG frames of a
moving texture; the table gives ms per frame for each step (``Detector.prepare``, ``infer``,
``boxes``) and for the whole, and their ratio to reading the JPEG frame (the baseline).
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np

SIZES = {"1080p": (1920, 1080), "1242x375": (1242, 375)}
INPUT = 640
CLASSES = 10
CANDIDATES = 40  # boxes of the first frame over score_min
STAGES = (24, 48, 96, 192, 384)  # channels after each stride-2 stage: 320, 160, 80, 40, 20 px
HEADS = (2, 3, 4)  # the stages the head reads: 80, 40 and 20 px (8400 boxes at 640)
MISSING_ONNX = ("signmap bench detector builds its model with the onnx package, a test extra: "
                "pip install -e '.[test]'")


class BenchError(Exception):
    """The bench cannot run; ``str(exc)`` says why."""


def _graph(shift: float, logits: bool, seed: int = 0):
    """The model (onnx ModelProto), its GFLOPs and parameters; ``logits``: output the class logits
    before the shift and sigmoid instead (to choose ``shift``)."""
    try:
        from onnx import TensorProto, helper, numpy_helper
    except ImportError:
        raise BenchError(MISSING_ONNX) from None
    rng = np.random.default_rng(seed)
    nodes, inits = [], []
    flops = 0.0

    def const(name: str, value) -> str:
        inits.append(numpy_helper.from_array(np.asarray(value), name))
        return name

    def conv(x: str, name: str, cin: int, cout: int, k: int, stride: int, side: int,
             act: bool = True) -> str:
        nonlocal flops
        w = rng.normal(0, np.sqrt(2.0 / (cin * k * k)), (cout, cin, k, k)).astype(np.float32)
        nodes.append(helper.make_node(
            "Conv", [x, const(f"{name}.w", w), const(f"{name}.b", np.zeros(cout, np.float32))],
            [f"{name}.conv"], kernel_shape=[k, k], strides=[stride, stride], pads=[k // 2] * 4))
        flops += 2.0 * cout * cin * k * k * side * side
        if not act:
            return f"{name}.conv"
        nodes.extend([helper.make_node("Sigmoid", [f"{name}.conv"], [f"{name}.sig"]),
                      helper.make_node("Mul", [f"{name}.conv", f"{name}.sig"], [name])])  # SiLU
        return name

    x, cin, side, maps = "images", 3, INPUT, []
    for i, cout in enumerate(STAGES):
        side //= 2
        x = conv(x, f"s{i}", cin, cout, 3, 2, side)
        if i:
            x = conv(x, f"s{i}b", cout, cout, 3, 1, side)
        cin = cout
        if i in HEADS:
            maps.append((x, cout, side))
    flat = const("flat", np.array([1, 4 + CLASSES, -1], np.int64))
    heads = []
    for j, (m, c, s) in enumerate(maps):
        h = conv(m, f"head{j}", c, 4 + CLASSES, 1, 1, s, act=False)
        nodes.append(helper.make_node("Reshape", [h, flat], [f"head{j}.flat"]))
        heads.append(f"head{j}.flat")
    n_boxes = sum(s * s for _, _, s in maps)
    axis1 = const("axis1", np.array([1], np.int64))
    c4 = const("c4", np.array([4], np.int64))
    nodes += [helper.make_node("Concat", heads, ["raw"], axis=2),  # [1, 4 + nc, 8400]
              helper.make_node("Slice", ["raw", c4, const("c_end", np.array([4 + CLASSES])),
                                         axis1], ["cls_raw"])]
    if logits:
        out_name, out_shape = "cls_raw", [1, CLASSES, n_boxes]
    else:
        out_name, out_shape = "output0", [1, 4 + CLASSES, n_boxes]
        nodes += [helper.make_node("Slice", ["raw", const("c0", np.array([0])), c4, axis1],
                                   ["box_raw"]),
                  helper.make_node("Sigmoid", ["box_raw"], ["box_sig"]),
                  # cx, cy anywhere in the input; w, h 8 to 136 px
                  helper.make_node("Mul", ["box_sig", const("box_scale", np.array(
                      [INPUT, INPUT, 128, 128], np.float32).reshape(1, 4, 1))], ["box_scaled"]),
                  helper.make_node("Add", ["box_scaled", const("box_offset", np.array(
                      [0, 0, 8, 8], np.float32).reshape(1, 4, 1))], ["boxes"]),
                  helper.make_node("Sub", ["cls_raw", const("shift", np.float32(shift))],
                                   ["cls_shifted"]),
                  helper.make_node("Sigmoid", ["cls_shifted"], ["scores"]),
                  helper.make_node("Concat", ["boxes", "scores"], ["output0"], axis=1)]
    graph = helper.make_graph(
        nodes, "bench-detector",
        [helper.make_tensor_value_info("images", TensorProto.FLOAT, [1, 3, INPUT, INPUT])],
        [helper.make_tensor_value_info(out_name, TensorProto.FLOAT, out_shape)], initializer=inits)
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8
    helper.set_model_props(model, {"names": repr({i: f"sign{i}" for i in range(CLASSES)})})
    params = sum(int(np.prod(t.dims)) for t in inits if t.name.endswith((".w", ".b")))
    return model, flops / 1e9, params


def build_model(path: Path, first_frame: np.ndarray,
                score_min: float) -> tuple[Path, float, int]:
    """The bench's model at ``path``, its class scores shifted so that ``CANDIDATES`` boxes of
    ``first_frame`` (BGR) pass ``score_min``; returns it, its GFLOPs and parameters."""
    import onnxruntime as ort

    from app.pipeline.detect.model import letterbox

    probe, *_ = _graph(0.0, logits=True)  # BenchError first when onnx is missing
    import onnx

    options = ort.SessionOptions()
    options.log_severity_level = 3
    session = ort.InferenceSession(probe.SerializeToString(), sess_options=options,
                                   providers=["CPUExecutionProvider"])
    img = letterbox(first_frame, INPUT)[0]
    blob = np.ascontiguousarray(img[:, :, ::-1].transpose(2, 0, 1)[None], np.float32) / 255.0
    best = np.sort(session.run(None, {"images": blob})[0][0].max(axis=0))
    shift = float(best[-CANDIDATES]) - float(np.log(score_min / (1 - score_min))) - 1e-3
    model, gflops, params = _graph(shift, logits=False)
    onnx.checker.check_model(model)
    onnx.save(model, str(path))
    return path, gflops, params


def _frames(n: int, width: int, height: int, out: Path) -> list[Path]:
    """``n`` JPEG frames (quality 90) of a blurred noise texture panning by 6 px a frame."""
    import cv2

    rng = np.random.default_rng(0)
    texture = cv2.GaussianBlur(rng.integers(0, 255, (height, width + 6 * n, 3), np.uint8),
                               (0, 0), 3)
    out.mkdir(parents=True, exist_ok=True)
    paths = []
    for i in range(n):
        path = out / f"{i:06d}.jpg"
        cv2.imwrite(str(path), np.ascontiguousarray(texture[:, 6 * i:6 * i + width]),
                    [cv2.IMWRITE_JPEG_QUALITY, 90])
        paths.append(path)
    return paths


def _ms(t0: float) -> float:
    return 1000.0 * (time.perf_counter() - t0)


def measure(n_frames: int, size: str = "1080p") -> str:
    """The bench's markdown: ``n_frames`` frames of ``size`` through the detector."""
    import cv2
    import onnxruntime as ort

    from app.pipeline.detect import DetectorConfig, detect_journey, load_detector
    from app.pipeline.types import Frame, Journey

    width, height = SIZES[size]
    with tempfile.TemporaryDirectory(prefix="signmap-detector-bench-") as tmp:
        paths = _frames(n_frames, width, height, Path(tmp) / "frames")
        config = DetectorConfig(model=Path(tmp) / "bench.onnx")
        _, gflops, params = build_model(config.model, cv2.imread(str(paths[0])),
                                        config.score_min)
        t0 = time.perf_counter()
        detector = load_detector(config)
        load_ms = _ms(t0)
        detector.detect(cv2.imread(str(paths[0])))  # warm-up
        steps = {k: [] for k in ("read", "prepare", "infer", "boxes")}
        candidates, kept = [], []
        for path in paths:
            t0 = time.perf_counter()
            bgr = cv2.imread(str(path), cv2.IMREAD_COLOR)
            steps["read"].append(_ms(t0))
            t0 = time.perf_counter()
            blob, r, left, top = detector.prepare(bgr)
            steps["prepare"].append(_ms(t0))
            t0 = time.perf_counter()
            out = detector.infer(blob)
            steps["infer"].append(_ms(t0))
            t0 = time.perf_counter()
            boxes = detector.boxes(out, r, left, top, width, height)
            steps["boxes"].append(_ms(t0))
            candidates.append(int((out[0, 4:].max(axis=0) >= config.score_min).sum()))
            kept.append(len(boxes))
        zeros = np.zeros(n_frames)
        journey = Journey("bench", [Frame(p.stem, p, float(i)) for i, p in enumerate(paths)],
                          zeros, zeros, zeros, [], width, height)
        t0 = time.perf_counter()
        detect_journey(journey, detector)
        total = _ms(t0) / n_frames
    mean = {k: float(np.mean(v)) for k, v in steps.items()}
    base = mean["read"]
    rows = [("read the JPEG frame, cv2.imread (baseline)", base),
            ("letterbox to 640 + input blob (`Detector.prepare`)", mean["prepare"]),
            ("inference, onnxruntime on 2 threads (`Detector.infer`)", mean["infer"]),
            ("decode + score filter + NMS (`Detector.boxes`)", mean["boxes"]),
            ("total: `detect_journey` per frame (read, all of the above, tracking)", total)]
    md = [f"# Sign detector time per frame: {n_frames} {width}x{height} JPEG frames, input "
          f"{INPUT} px",
          "",
          f"Model: {len(STAGES)} stride-2 conv stages + YOLOv8-like head, {gflops:.1f} GFLOPs, "
          f"{params / 1e6:.1f} M parameters, "
          f"output [1, {4 + CLASSES}, 8400], random weights; onnxruntime {ort.__version__}, "
          f"CPU, 2 intra-op threads. `load_detector` {load_ms:.0f} ms (once per journey). Boxes "
          f"over score_min {np.mean(candidates):.0f} per frame, {np.mean(kept):.0f} kept after "
          "NMS. Means over the frames after one warm-up frame.",
          "",
          "| step | ms per frame | ratio to the JPEG read |",
          "| --- | --- | --- |"]
    md += [f"| {name} | {ms:.1f} | {ms / base:.1f} |" for name, ms in rows]
    return "\n".join(md) + "\n"


def run_detector_bench(n_frames: int, out_dir: Path, size: str = "1080p") -> Path:
    """Run the bench and write its markdown to ``out_dir``; BenchError when it cannot run."""
    if n_frames < 1:
        raise BenchError("--frames must be at least 1")
    md = measure(n_frames, size)
    out_dir.mkdir(parents=True, exist_ok=True)
    path = out_dir / f"detector-time-{size}.md"
    path.write_text(md)
    return path
