"""GPS logs as receivers and apps write them, for tests and benches: an NMEA 0183 log (RMC + GGA
per fix, checksummed) and a GPX track. Both are timed ``t0_utc + timestamp_s`` and read back
(``bundle.video.nmea.parse_nmea``, ``bundle.gps.read_gpx``) to the same numbers: positions to
1e-9 degrees, times to the millisecond, ``alt_m`` ellipsoidal."""

from __future__ import annotations

import math
from datetime import datetime, timedelta, timezone
from functools import reduce
from operator import xor

import numpy as np

from app.synth.bundle import gps_gpx


def _utc(t0_utc: datetime) -> datetime:
    return t0_utc.astimezone(timezone.utc) if t0_utc.tzinfo else t0_utc.replace(tzinfo=timezone.utc)


def _sentence(body: str) -> str:
    return f"${body}*{reduce(xor, body.encode('ascii'), 0):02X}\r\n"


def _ddmm(value_deg: float, width: int, positive: str, negative: str) -> tuple[str, str]:
    # 7 decimals of a minute are 2e-9 degrees: well inside the round trip's 1e-7.
    minutes = round(abs(value_deg) * 60.0, 7)
    deg, minute = divmod(minutes, 60.0)
    return f"{int(deg):0{width}d}{minute:010.7f}", positive if value_deg >= 0 else negative


def nmea_log(t0_utc: datetime, timestamp_s, lat_deg, lon_deg, alt_m, *,
             geoid_sep_m: float = 47.0, hdop: float = 0.9, talker: str = "GP") -> str:
    """An RMC and a GGA sentence per fix at ``t0_utc + timestamp_s`` (times rounded to the
    millisecond), CRLF-ended. GGA altitude is above the geoid: ``alt_m - geoid_sep_m`` with
    ``geoid_sep_m`` as its separation, so a reader gives back ``alt_m``; NaN leaves it empty."""
    start_ms = round(_utc(t0_utc).timestamp() * 1000)
    epoch = datetime(1970, 1, 1, tzinfo=timezone.utc)
    out = []
    for t, lat, lon, alt in zip(np.asarray(timestamp_s, float), lat_deg, lon_deg, alt_m):
        when = epoch + timedelta(milliseconds=start_ms + round(float(t) * 1000))
        hms = when.strftime("%H%M%S.") + f"{when.microsecond // 1000:03d}"
        lat_text, ns = _ddmm(float(lat), 2, "N", "S")
        lon_text, ew = _ddmm(float(lon), 3, "E", "W")
        msl = "" if math.isnan(alt) else f"{float(alt) - geoid_sep_m:.3f}"
        out.append(_sentence(f"{talker}GGA,{hms},{lat_text},{ns},{lon_text},{ew},1,08,{hdop:.1f},"
                             f"{msl},M,{geoid_sep_m:.3f},M,,"))
        out.append(_sentence(f"{talker}RMC,{hms},A,{lat_text},{ns},{lon_text},{ew},,,"
                             f"{when.strftime('%d%m%y')},,,A"))
    return "".join(out)


def gpx_track(t0_utc: datetime, timestamp_s, lat_deg, lon_deg, alt_m) -> str:
    """A GPX 1.1 track, one point per fix at ``t0_utc + timestamp_s`` (to the millisecond, UTC);
    ``alt_m`` finite (``<ele>`` on every point)."""
    return gps_gpx(_utc(t0_utc), timestamp_s, lat_deg, lon_deg, alt_m)
