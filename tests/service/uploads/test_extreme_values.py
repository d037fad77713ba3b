"""Every field of a bundle, swept with extreme values (issue 70, item 2): each is refused at the
upload with a 422 whose detail names the file, the row and the field, and nothing is stored. Before,
a 5000-digit track id, an altitude of 1e308 or a NUL in a class passed the upload (202) and failed
the job with an internal error.

One test per field (over SQLite and PostgreSQL); the values a field is swept with are looped over
inside it, each a separate upload through one app.
"""

from __future__ import annotations

import csv
import io
import re

import pytest

from app.pipeline.bundle import check_bundle
from tests.utils import bundle_factory as bf
from tests.utils.stack import auth

HUGE_INT = "9" * 5000
LONG_TEXT = "x" * 10_000
# Text no id may hold: NUL (PostgreSQL), line breaks (log forgery), escapes, and sheer length.
BAD_TEXT = ("a\x00b", "a\nERROR FORGED admin key leaked", "a\rb", "\x1b[31mred", "a\u2028b",
            LONG_TEXT)
NOT_FINITE = ("1e308", "nan", "inf", "-inf", HUGE_INT, LONG_TEXT)


def _csv(header, rows) -> bytes:
    """A CSV as a client would write it: values with commas or newlines quoted."""
    out = io.StringIO()
    csv.writer(out, lineterminator="\r\n").writerows([header, *rows])
    return out.getvalue().encode()


def _gps_fix(column: str, value: str) -> dict[str, bytes]:
    rows = [list(r) for r in bf.gps_rows()]
    rows[3][bf.GPS_HEADER.index(column)] = value  # file row 5: a fix (frame-less) row
    return {"gps.csv": _csv(bf.GPS_HEADER, rows)}


def _detection(column: str, value: str) -> dict[str, bytes]:
    row = ["000001", "7", "stop", "1", "1", "5", "5", "0.5"]
    row[bf.DETECTIONS_HEADER.index(column)] = value
    return {"detections.csv": _csv(bf.DETECTIONS_HEADER, [*bf.detection_rows(), row])}


def _manifest(path: str, raw_json: str) -> dict[str, bytes]:
    """The valid manifest with the field at ``path`` ("camera_prior.fx") set to raw JSON text
    (json.dumps cannot write a 5000-digit integer)."""
    prior = {"fx": 80.0, "fy": 80.0, "cx": 31.5, "cy": 23.5, "k1": 0.0, "k2": 0.0}
    field = path.split(".")[-1]
    if path.startswith("camera_prior."):
        text = bf.manifest_bytes(camera_prior={**prior, field: "@@"}).decode()
    else:
        text = bf.manifest_bytes(**{field: "@@"}).decode()
    return {"manifest.json": text.replace('"@@"', raw_json).encode()}


def _json_str(value: str) -> str:
    return '"' + value.replace("\\", "\\\\").replace('"', '\\"').replace("\n", "\\n").replace(
        "\r", "\\r").replace("\x00", "\\u0000").replace("\x1b", "\\u001b") + '"'


def _gpx_ele(value: str) -> dict[str, bytes]:
    gpx = bf.valid_files(gps="gpx")["gps.gpx"].decode()
    return {"gps.gpx": gpx.replace("<ele>112.00</ele>", f"<ele>{value}</ele>", 1).encode()}


NUMBERS_AS_JSON = ("1e308", "-1e308", "NaN", "Infinity", "-Infinity", HUGE_INT, '"80"')

# field -> (the pattern the detail must match, [(what the bundle's files become, value shown)])
SWEEP: dict[str, tuple[str, list[tuple[dict[str, bytes], str]]]] = {
    "gps.csv frame": (r"gps\.csv row \d+: frame", [(_gps_fix("frame", v), v) for v in BAD_TEXT]),
    "gps.csv timestamp_s": (r"gps\.csv row 5: timestamp_s", [
        (_gps_fix("timestamp_s", v), v) for v in (*NOT_FINITE, "-1e11", "1e11")]),
    "gps.csv lat": (r"gps\.csv row 5: lat", [
        (_gps_fix("lat", v), v) for v in (*NOT_FINITE, "-90.5", "")]),
    "gps.csv lon": (r"gps\.csv row 5: lon", [
        (_gps_fix("lon", v), v) for v in (*NOT_FINITE, "180.5", "")]),
    "gps.csv alt_m": (r"gps\.csv row 5: alt_m", [
        (_gps_fix("alt_m", v), v) for v in (*NOT_FINITE, "-1000.5", "20000.5")]),
    "gps.gpx ele": (r"gps\.gpx track point 1: ele", [
        ({**_gpx_ele(v), "gps.csv": None}, v) for v in ("1e308", "nan", "inf", "30000")]),
    "detections.csv frame": (r"detection row \d+ names frame", [
        (_detection("frame", v), v) for v in BAD_TEXT]),
    "detections.csv track_id": (r"detection row \d+: track_id", [
        (_detection("track_id", v), v) for v in (HUGE_INT, *BAD_TEXT)]),
    "detections.csv class": (r"detection row \d+: class", [
        (_detection("class", v), v) for v in BAD_TEXT]),
    **{f"detections.csv {c}": (rf"detection row 10: (box .* \({c} is|{c} is)", [
        (_detection(c, v), v) for v in (*NOT_FINITE, "-1e308", "")])
       for c in ("x1", "y1", "x2", "y2")},
    "detections.csv score": (r"detection row 10: score", [
        (_detection("score", v), v) for v in ("nan", "inf", "-inf", LONG_TEXT)]),
    "manifest format": (r"manifest\.json format is", [
        (_manifest("format", j), j) for j in (_json_str("a\x00b"), _json_str(LONG_TEXT), "1e308",
                                               HUGE_INT)]),
    **{f"manifest {f}": (rf"manifest\.json is invalid: {f}", [
        (_manifest(f, j), j) for j in (*(_json_str(v) for v in BAD_TEXT), "1e308", HUGE_INT)])
       for f in ("camera_id", "vehicle_id", "captured_at")},
    **{f"manifest camera_prior.{f}": (rf"manifest\.json is invalid: camera_prior\.{f}", [
        (_manifest(f"camera_prior.{f}", j), j) for j in NUMBERS_AS_JSON])
       for f in ("fx", "fy", "cx", "cy", "k1", "k2")},
    "frame file name": (r"frame file name", [
        ({"frames/000004.png": None, f"frames/0000{c}4.png": bf.image_bytes(seed=4)}, repr(c))
        for c in ("\n", "\x1b", "\u2028", "9" * 300)]),
}


def _bundle(changes: dict[str, bytes | None], gpx: bool = False) -> bytes:
    files = bf.valid_files(gps="gpx" if gpx else "csv")
    for name, data in changes.items():
        if data is None:
            files.pop(name, None)
        else:
            files[name] = data
    return bf.zip_bytes(files)


@pytest.mark.parametrize("field", list(SWEEP))
def test_an_extreme_value_in_any_field_is_refused_at_the_upload(stack, field):
    pattern, cases = SWEEP[field]
    key = stack.key("fleet")
    with stack.client() as client:
        for changes, value in cases:
            data = _bundle(changes, gpx=field.startswith("gps.gpx"))
            response = client.post("/api/v1/journeys", headers=auth(key),
                                   files={"bundle": ("journey.zip", data, "application/zip")})
            shown = repr(value[:40])
            assert response.status_code == 422, f"{field} = {shown}: {response.text[:300]}"
            detail = response.json()["detail"]
            assert re.search(pattern, detail), f"{field} = {shown}: {detail[:300]}"
            # The detail does not send a 10,000-character value back whole.
            assert len(detail) < 500, f"{field} = {shown}: a detail of {len(detail)} characters"
        assert stack.count_journeys(key) == 0
        assert stack.stored_files() == []


def test_the_sweep_values_are_in_range_elsewhere(tmp_path):
    """The bundle each sweep case starts from is valid: only the swept value is wrong."""
    check_bundle(bf.write_zip(tmp_path / "ok.zip", bf.valid_files()))
    check_bundle(bf.write_zip(tmp_path / "gpx.zip", bf.valid_files(gps="gpx")))
    ok = _bundle({**_manifest("camera_prior.fx", "80.0"), **_detection("track_id", "7"),
                  **_gps_fix("alt_m", "-999")})
    (tmp_path / "edge.zip").write_bytes(ok)
    assert check_bundle(tmp_path / "edge.zip").n_detections == 9


def test_an_implausible_accuracy_is_ignored_with_a_warning(tmp_path):
    """accuracy_m is this service's extension of a contract that ignores extra columns: a value
    that is no accuracy is left out with a warning (docs/journey-format.md), never reaches the
    job, and so never fails it."""
    rows = [[*r, ""] for r in bf.gps_rows()]
    for i, value in zip((0, 3, 6, 8), ("1e308", "nan", HUGE_INT, "a\x00b")):
        rows[i][-1] = value
    files = {**bf.valid_files(), "gps.csv": _csv((*bf.GPS_HEADER, "accuracy_m"), rows)}
    check = check_bundle(bf.write_zip(tmp_path / "b.zip", files))
    assert any("accuracy_m ignored on 4 row(s)" in w for w in check.warnings), check.warnings
