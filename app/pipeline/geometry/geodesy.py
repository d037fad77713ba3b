"""WGS84 <-> a local metric frame, with pyproj.

The default frame is a local East-North-Up tangent plane (``enu``) at an origin fix: x east, y north,
z up, metres. ``mercator`` is the paper's scaled spherical Mercator (eq. 3-4, r = 6378137 m, scale
cos(lat0)), shifted so the origin is at (0, 0, alt0 -> 0), kept so our figures can be compared with
the paper's. Altitude is ellipsoidal height as uploaded; when a journey has none, 0 is used and
altitudes are not reported.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np
from pyproj import Transformer
from pyproj.enums import TransformDirection


@dataclass(frozen=True)
class LocalFrame:
    lat0_deg: float
    lon0_deg: float
    alt0_m: float = 0.0
    kind: Literal["enu", "mercator"] = "enu"

    def _transformer(self) -> Transformer:
        if self.kind == "enu":
            pipeline = (
                "+proj=pipeline +step +proj=unitconvert +xy_in=deg +xy_out=rad "
                "+step +proj=cart +ellps=WGS84 "
                f"+step +proj=topocentric +ellps=WGS84 +lat_0={self.lat0_deg!r} "
                f"+lon_0={self.lon0_deg!r} +h_0={self.alt0_m!r}"
            )
        else:
            scale = math.cos(math.radians(self.lat0_deg))
            pipeline = (
                "+proj=pipeline +step +proj=unitconvert +xy_in=deg +xy_out=rad "
                f"+step +proj=merc +a=6378137 +b=6378137 +k_0={scale!r}"
            )
        return Transformer.from_pipeline(pipeline)

    def _mercator_origin(self, t: Transformer) -> tuple[float, float]:
        x0, y0 = t.transform(self.lon0_deg, self.lat0_deg)
        return float(x0), float(y0)

    def to_local(self, lat_deg, lon_deg, alt_m=None) -> np.ndarray:
        """WGS84 degrees (and metres) -> local metric coordinates, shape (N, 3)."""
        lat = np.atleast_1d(np.asarray(lat_deg, dtype=float))
        lon = np.atleast_1d(np.asarray(lon_deg, dtype=float))
        alt = np.zeros_like(lat) if alt_m is None else np.atleast_1d(np.asarray(alt_m, float))
        alt = np.where(np.isfinite(alt), alt, self.alt0_m)
        t = self._transformer()
        if self.kind == "enu":
            x, y, z = t.transform(lon, lat, alt)
            return np.column_stack([x, y, z])
        x0, y0 = self._mercator_origin(t)
        x, y = t.transform(lon, lat)
        return np.column_stack([np.asarray(x) - x0, np.asarray(y) - y0, alt - self.alt0_m])

    def to_geodetic(self, xyz) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Local metric coordinates (N, 3) -> (lat_deg, lon_deg, alt_m), each shape (N,)."""
        xyz = np.atleast_2d(np.asarray(xyz, dtype=float))
        t = self._transformer()
        if self.kind == "enu":
            lon, lat, alt = t.transform(xyz[:, 0], xyz[:, 1], xyz[:, 2],
                                        direction=TransformDirection.INVERSE)
            return np.asarray(lat), np.asarray(lon), np.asarray(alt)
        x0, y0 = self._mercator_origin(t)
        lon, lat = t.transform(xyz[:, 0] + x0, xyz[:, 1] + y0, direction=TransformDirection.INVERSE)
        return np.asarray(lat), np.asarray(lon), xyz[:, 2] + self.alt0_m


def frame_at(lat_deg: float, lon_deg: float, alt_m: float | None,
             kind: Literal["enu", "mercator"] = "enu") -> LocalFrame:
    """A local frame whose origin is the given fix (altitude 0 when unknown)."""
    alt = float(alt_m) if alt_m is not None and math.isfinite(alt_m) else 0.0
    return LocalFrame(float(lat_deg), float(lon_deg), alt, kind)
