"""Signmap's own sign detector, for journeys whose bundle holds no ``detections.csv``.

``model`` loads an ONNX object detector (YOLOv5/v7, YOLOv8/v11 or an export with NMS built in) and
finds boxes in one image; ``journey`` runs it over a journey's frames and tracks the boxes.
"""

from app.pipeline.detect.journey import apply_detector, bundle_has_detections, detect_journey
from app.pipeline.detect.model import Box, Detector, DetectorConfig, DetectorError, load_detector

__all__ = ["Box", "Detector", "DetectorConfig", "DetectorError", "apply_detector",
           "bundle_has_detections", "detect_journey", "load_detector"]
