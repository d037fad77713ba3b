"""An NMEA 0183 log (``gps.nmea``) -> ``GpsLog``: what a dash cam's or a logger's receiver wrote.

Rules (the file is treated as hostile; docs/decisions/nmea-reader.md says why it is parsed here):

* Only RMC and GGA sentences are read, from any talker (GP, GN, GL, GA, BD...), at any rate; other
  sentences (GSV, GSA, VTG, proprietary ones) are ignored and counted.
* A line must be one sentence, ``$...*HH``, printable ASCII, at most ``MAX_LINE_CHARS``; a line
  that is not, or whose checksum is wrong or missing, or whose RMC/GGA fields do not parse (or give
  a position off the globe, an altitude outside ``MIN_ALT_M..MAX_ALT_M``) is skipped and counted,
  never fatal. So is a sentence without a fix: GGA quality 0, RMC status V or mode N.
* Times are UTC. RMC gives date and time, GGA the time of day only: a GGA takes its date from the
  RMC sentences (the last one before it, a day later when its time of day went back by more than
  12 h: midnight passed; GGA fixes before the first RMC count back from it). A log without any RMC
  date is refused. Two-digit years are 1980..2079.
* The RMC and GGA of one epoch (consecutive sentences with the same time of day) are one fix:
  position from whichever comes first, altitude and HDOP from GGA.
* GGA altitude is above mean sea level (the geoid); its geoid separation is added to give the
  ellipsoidal height ``alt_m`` means everywhere else. Without a separation the altitude is left
  out (NaN; a geoid is up to ~100 m off the ellipsoid).
* ``accuracy_m`` = HDOP x ``UERE_M`` (see there), NaN without a GGA HDOP.
* Fixes come out strictly increasing in time: a fix at the time of an earlier one is dropped, as
  is one earlier than a fix before it (both counted).
* ``notes``: one line per kind of skip, with the count and the first line, and the rates seen.
  No fix left is a BundleError counting what was refused; so is more than ``max_lines`` lines.

Memory: the numbers of the kept fixes (``array('d')``) and one line at a time.
"""

from __future__ import annotations

import io
import math
import re
from array import array
from collections import Counter
from dataclasses import dataclass
from datetime import date, datetime, timedelta, timezone
from functools import reduce
from operator import xor
from typing import BinaryIO, Iterator

import numpy as np

from app.pipeline.bundle.gps import (MAX_ACCURACY_M, MAX_ALT_M, MIN_ALT_M, GpsFixes, GpsLog,
                                     NumberedLabels, check_position)
from app.pipeline.types import BundleError

# NMEA 0183 caps a sentence at 82 characters; receivers' extended sentences run longer, but
# nothing a receiver writes comes near 200. Longer is junk, and is never held whole.
MAX_LINE_CHARS = 200
# HDOP x sigma_UERE is the drms horizontal error, the radius holding 63-68 % of fixes (by the
# error ellipse's shape): the 68 % radius that ``accuracy_m`` means. sigma_UERE, the 1-sigma range
# error of single-frequency code without corrections (ionosphere, troposphere, multipath, clocks,
# orbits), is a few metres; 2.5 m is a modern multi-constellation receiver's. It is a stated
# figure, not a measurement: where it is too small a sign's std_m claims too much precision.
UERE_M = 2.5
DAY_MS = 86_400_000
HALF_DAY_MS = DAY_MS // 2
_EPOCH_ORDINAL = date(1970, 1, 1).toordinal()
_SENTENCE = re.compile(rb"\$([^*]*)(?:\*(.*))?", re.DOTALL)
_PRINTABLE = re.compile(rb"[\x20-\x7e]*")
# A talker never starts with P: that is a proprietary sentence ("PGRMC" is Garmin's, no RMC).
_ADDRESS = re.compile(r"[A-OQ-Z][A-Z0-9]([A-Z]{3})|P[A-Z0-9]{1,8}")
_TIME = re.compile(r"([01]\d|2[0-3])([0-5]\d)([0-5]\d(?:\.\d{1,6})?)")
_DATE = re.compile(r"(\d\d)(\d\d)(\d\d)")
_DEGREES = re.compile(r"(\d{1,3})([0-5]\d(?:\.\d{1,12})?)")
_NUMBER = re.compile(r"[-+]?\d{1,6}(?:\.\d{1,6})?")
_RMC, _GGA = 1, 2  # bits of a fix's sentence kinds

# Why lines are skipped, as "<n> line(s) <phrase>".
_SKIPS = {
    "long": f"longer than {MAX_LINE_CHARS} characters",
    "not_nmea": "not in NMEA form ($...*HH, printable ASCII)",
    "no_checksum": "without a checksum",
    "bad_checksum": "with a bad checksum",
    "bad_fields": "with RMC/GGA fields that do not parse",
    "no_fix": "without a fix (GGA quality 0, RMC status V)",
}


class _Skip(Exception):
    def __init__(self, kind: str):
        self.kind = kind


@dataclass(slots=True)
class _Epoch:
    """One epoch's fix being gathered from its RMC and GGA sentences (mutable while it is)."""

    tod_ms: int  # time of day, UTC
    line: int
    lat_deg: float
    lon_deg: float
    alt_m: float = math.nan
    accuracy_m: float = math.nan
    day: int | None = None  # days since 1970-01-01 (from RMC)
    kinds: int = 0


def _lines(stream: BinaryIO) -> Iterator[bytes]:
    """Lines split at LF, each cut after MAX_LINE_CHARS + 3 bytes (the rest of it read and thrown
    away in blocks), so a line without an end costs no memory."""
    limit = MAX_LINE_CHARS + 3
    while line := stream.readline(limit):
        if len(line) == limit and not line.endswith(b"\n"):
            while (rest := stream.readline(1 << 16)) and not rest.endswith(b"\n"):
                pass
        yield line


def _time_of_day_ms(text: str) -> int:
    m = _TIME.fullmatch(text)
    if not m:
        raise _Skip("bad_fields")
    return (int(m[1]) * 3600 + int(m[2]) * 60) * 1000 + round(float(m[3]) * 1000)


def _day(text: str) -> int:
    m = _DATE.fullmatch(text)
    if not m:
        raise _Skip("bad_fields")
    year = int(m[3]) + (1900 if int(m[3]) >= 80 else 2000)
    try:
        return date(year, int(m[2]), int(m[1])).toordinal() - _EPOCH_ORDINAL
    except ValueError:
        raise _Skip("bad_fields") from None


def _coordinate(value: str, hemisphere: str, negative: str, positive: str) -> float:
    m = _DEGREES.fullmatch(value)
    if not m or hemisphere not in (negative, positive):
        raise _Skip("bad_fields")
    deg = int(m[1]) + float(m[2]) / 60.0
    return -deg if hemisphere == negative else deg


def _position(f: list[str], i: int, line: int) -> tuple[float, float]:
    lat = _coordinate(f[i], f[i + 1], "S", "N")
    lon = _coordinate(f[i + 2], f[i + 3], "W", "E")
    try:
        check_position(lat, lon, f"line {line}")
    except BundleError:
        raise _Skip("bad_fields") from None
    return lat, lon


def _number(text: str) -> float:
    if not _NUMBER.fullmatch(text):
        raise _Skip("bad_fields")
    return float(text)


def _rmc(f: list[str], line: int) -> _Epoch:
    if len(f) < 10:
        raise _Skip("bad_fields")
    if f[2] != "A" or (len(f) > 12 and f[12] == "N"):  # mode N (NMEA 2.3): not valid
        raise _Skip("no_fix")
    lat, lon = _position(f, 3, line)
    return _Epoch(_time_of_day_ms(f[1]), line, lat, lon, day=_day(f[9]), kinds=_RMC)


def _gga(f: list[str], line: int, no_geoid: list[int]) -> _Epoch:
    if len(f) < 12 or not f[6].isdigit():
        raise _Skip("bad_fields")
    if int(f[6]) == 0:
        raise _Skip("no_fix")
    lat, lon = _position(f, 2, line)
    alt = math.nan
    if f[9]:
        if not f[11]:
            no_geoid.append(line)
        else:
            alt = _number(f[9]) + _number(f[11])
            if not MIN_ALT_M <= alt <= MAX_ALT_M:
                raise _Skip("bad_fields")
    accuracy = _number(f[8]) * UERE_M if f[8] else math.nan
    if not 0.0 < accuracy < MAX_ACCURACY_M:
        accuracy = math.nan
    return _Epoch(_time_of_day_ms(f[1]), line, lat, lon, alt, accuracy, kinds=_GGA)


def _sentence(raw: bytes, line: int, other: Counter, no_geoid: list[int]) -> _Epoch:
    """One line's fix, or _Skip saying why there is none."""
    text = raw.strip(b" \t\r\n")
    if len(text) > MAX_LINE_CHARS:
        raise _Skip("long")
    m = _SENTENCE.fullmatch(text)
    if not m or not _PRINTABLE.fullmatch(m[1]) or b"$" in m[1]:
        raise _Skip("not_nmea")
    body, checksum = m[1], m[2]
    if checksum is None:
        raise _Skip("no_checksum")
    if not re.fullmatch(rb"[0-9A-Fa-f]{2}", checksum) or int(checksum, 16) != reduce(xor, body, 0):
        raise _Skip("bad_checksum")
    fields = body.decode("ascii").split(",")
    address = _ADDRESS.fullmatch(fields[0])
    if not address:
        raise _Skip("not_nmea")
    if address[1] == "RMC":
        return _rmc(fields, line)
    if address[1] == "GGA":
        return _gga(fields, line, no_geoid)
    other[address[1] or fields[0]] += 1
    raise _Skip("other")


class _Columns:
    """The fixes' numbers, one array('d') each; ``day`` NaN until an RMC dates the fix."""

    def __init__(self):
        self.tod_ms, self.day, self.lat, self.lon, self.alt, self.acc, self.line, self.kinds = (
            array("d") for _ in range(8))
        self.known_day: int | None = None
        self.last_tod_ms = 0

    def add(self, e: _Epoch) -> None:
        if e.day is not None:
            self.known_day = e.day
        elif self.known_day is not None and e.tod_ms < self.last_tod_ms - HALF_DAY_MS:
            self.known_day += 1  # GGA only: the time of day went back, so midnight passed
        if self.known_day is not None:
            self.last_tod_ms = e.tod_ms
        for column, value in ((self.tod_ms, e.tod_ms), (self.lat, e.lat_deg),
                              (self.lon, e.lon_deg), (self.alt, e.alt_m), (self.acc, e.accuracy_m),
                              (self.line, e.line), (self.kinds, e.kinds),
                              (self.day, math.nan if self.known_day is None else self.known_day)):
            column.append(value)

    def values(self, name: str) -> np.ndarray:
        return np.frombuffer(getattr(self, name), np.float64)


def _merge(pending: _Epoch, e: _Epoch) -> None:
    """The other sentence of ``pending``'s epoch: GGA brings altitude and HDOP, RMC the date."""
    if e.kinds == _GGA:
        pending.alt_m, pending.accuracy_m = e.alt_m, e.accuracy_m
    else:
        pending.day = e.day
    pending.kinds |= e.kinds


def _lines_phrase(n: int, what: str) -> str:
    return f"{n} line{'s' if n != 1 else ''} {what}"


def _refused(name: str, n_lines: int, skips: Counter) -> BundleError:
    parts = [_lines_phrase(n_lines, "read")]
    parts += [f"{skips[k]} {_SKIPS[k]}" for k in _SKIPS if skips[k]]
    if skips["other"]:
        parts.append(f"{skips['other']} other sentences (not RMC or GGA)")
    return BundleError(f"{name} has no usable fix: {', '.join(parts)}; it needs RMC or GGA "
                       "sentences with a fix (checksummed, one per line)")


def _rate_note(t_s: np.ndarray, kinds: np.ndarray) -> str:
    rates = []
    for bit, label in ((_GGA, "GGA"), (_RMC, "RMC")):
        t = t_s[(kinds.astype(np.int64) & bit) != 0]
        if len(t) > 1:
            rates.append(f"{label} at {1.0 / float(np.median(np.diff(t))):.3g} Hz")
        elif len(t) == 1:
            rates.append(f"{label} once")
    return f"{len(t_s)} fixes over {t_s[-1] - t_s[0]:.1f} s: {', '.join(rates)}"


def parse_nmea(source: bytes | BinaryIO, *, max_lines: int | None = None,
               name: str = "gps.nmea") -> GpsLog:
    """An NMEA log (bytes, or a binary stream read as it goes) -> its fixes, timed from the first
    (module docstring for the rules); ``name`` names the file in messages."""
    stream = io.BytesIO(source) if isinstance(source, bytes) else source
    columns, skips, first_skip = _Columns(), Counter(), {}
    other, no_geoid = Counter(), []
    pending: _Epoch | None = None
    n_lines = 0
    for n_lines, raw in enumerate(_lines(stream), start=1):
        if max_lines is not None and n_lines > max_lines:
            raise BundleError(f"{name} has more than {max_lines} lines, the limit per journey; "
                              "split the journey into shorter ones")
        if not raw.strip():
            continue
        try:
            epoch = _sentence(raw, n_lines, other, no_geoid)
        except _Skip as skip:
            skips[skip.kind] += 1
            first_skip.setdefault(skip.kind, n_lines)
            continue
        if pending is None:
            pending = epoch
        elif pending.tod_ms == epoch.tod_ms and not pending.kinds & epoch.kinds:
            _merge(pending, epoch)
        else:
            columns.add(pending)
            pending = epoch
    if pending is not None:
        columns.add(pending)
    if not columns.tod_ms:
        raise _refused(name, n_lines, skips)
    return _log(name, columns, skips, first_skip, other, no_geoid)


def _log(name: str, columns: _Columns, skips: Counter, first_skip: dict, other: Counter,
         no_geoid: list[int]) -> GpsLog:
    day, tod_ms = columns.values("day").copy(), columns.values("tod_ms")
    dated = np.flatnonzero(np.isfinite(day))
    if not dated.size:
        raise BundleError(f"{name} has GGA fixes but no RMC sentence with a fix: GGA gives the "
                          "time of day only, the date comes from RMC; log RMC sentences too")
    k = int(dated[0])
    # Fixes before the first dated one: its day, or the day before when midnight lies between.
    day[:k] = day[k] - (tod_ms[:k] > tod_ms[k])
    abs_ms = day * DAY_MS + tod_ms
    latest_before = np.maximum.accumulate(np.concatenate(([-np.inf], abs_ms[:-1])))
    keep = abs_ms > latest_before
    line = columns.values("line")
    notes = [f"{_lines_phrase(skips[kind], phrase)} skipped (first: line {first_skip[kind]})"
             for kind, phrase in _SKIPS.items() if skips[kind]]
    if skips["other"]:
        notes.append(f"{skips['other']} other sentence{'s' if skips['other'] > 1 else ''} "
                     f"ignored ({', '.join(sorted(other)[:8])})")
    for what, dropped in (("repeating an earlier fix's time", abs_ms == latest_before),
                          ("earlier than a fix before them", abs_ms < latest_before)):
        if dropped.any():
            notes.append(f"{int(dropped.sum())} fix{'es' if dropped.sum() > 1 else ''} {what} "
                         f"dropped (first: line {int(line[np.argmax(dropped)])})")
    if no_geoid:
        notes.append(f"altitude left out of {len(no_geoid)} GGA sentence"
                     f"{'s' if len(no_geoid) > 1 else ''} without a geoid separation (first: "
                     f"line {no_geoid[0]}): their height is above sea level, not the ellipsoid")
    abs_ms = abs_ms[keep]
    t_s = (abs_ms - abs_ms[0]) / 1000.0
    notes.append(_rate_note(t_s, columns.values("kinds")[keep]))
    fixes = GpsFixes(t_s, columns.values("lat")[keep], columns.values("lon")[keep],
                     columns.values("alt")[keep],
                     NumberedLabels("line", line[keep].astype(np.int64)),
                     columns.values("acc")[keep])
    t0_utc = datetime(1970, 1, 1, tzinfo=timezone.utc) + timedelta(milliseconds=float(abs_ms[0]))
    return GpsLog(fixes, t0_utc, name, tuple(notes))
