"""``signmap bench detector`` on two frames: the table has its rows (no timing is asserted: the
bench reports ratios to a baseline of the same run), and without onnx it says what to install."""

from __future__ import annotations

import sys

import pytest

from app.cli import main

ROWS = ("read the JPEG frame", "letterbox to 640", "inference", "decode + score filter + NMS",
        "total: `detect_journey` per frame")


def test_the_bench_prints_a_row_per_step(tmp_path, capsys):
    assert main(["bench", "detector", "--frames", "2", "--size", "1242x375",
                 "--out", str(tmp_path)]) == 0
    md = (tmp_path / "detector-time-1242x375.md").read_text()
    assert md.startswith("# Sign detector time per frame: 2 1242x375 JPEG frames, input 640 px")
    rows = [line for line in md.splitlines() if line.startswith("| ") and "---" not in line]
    assert len(rows) == 1 + len(ROWS)
    for row, step in zip(rows[1:], ROWS):
        name, ms, ratio = [c.strip() for c in row.strip("|").split("|")]
        assert step in name and float(ms) > 0 and float(ratio) > 0, row
    assert "output [1, 14, 8400]" in md and md in capsys.readouterr().out


def test_without_onnx_the_bench_says_what_to_install(tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "onnx", None)  # import onnx raises ImportError
    with pytest.raises(SystemExit) as info:
        main(["bench", "detector", "--frames", "1", "--out", str(tmp_path)])
    assert str(info.value).startswith("signmap bench detector: ")
    assert "onnx package" in str(info.value) and "[test]" in str(info.value)
