"""Tests of the ONNX sign detector (issue 69): the three output layouts, letterbox and mapping
back to original pixels, NMS, class filter, refused models, a journey detected and tracked; the
"oracle" detector of the end-to-end test (``oracle``) and ``signmap bench detector`` (its home,
tests/bench, is full)."""
