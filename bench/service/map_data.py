"""Synthetic fused maps for ``signmap bench map``: N map signs over a country-sized region, most of
them in cities, bulk-loaded (PostgreSQL COPY, SQLite executemany of tuples) and kept between runs.

The layout is fixed by (N, seed), so a database that already holds exactly this map is reused."""

from __future__ import annotations

import json
from dataclasses import dataclass
from datetime import datetime, timedelta, timezone

import numpy as np
from sqlalchemy import func, select, text

from app.service.db.session import get_engine, session_scope, upgrade
from app.service.db.models import JourneyRow, MapSignRow

# A 4 x 6 degree country with 20 cities; 70 % of the signs within a few km of a city centre.
REGION = (6.0, 48.0, 12.0, 52.0)  # min lon, min lat, max lon, max lat
N_CITIES = 20
CITY_SHARE = 0.7
CITY_SIGMA_DEG = 0.03  # ~3 km
CITY_BOX_DEG = 0.1  # the bench's "city-sized" bbox: ~7 x 11 km around a city centre
CLASSES = ("stop", "give_way", "speed_limit_30", "speed_limit_50", "no_entry", "no_parking",
           "pedestrian_crossing", "priority_road", "roundabout", "one_way")
STATES = ("confirmed", "new", "possibly_removed")
COLUMNS = ("id", "class", "lat_deg", "lon_deg", "alt_m", "cov_enu", "std_m", "n_journeys",
           "n_observations", "first_seen_at", "last_seen_at", "state", "evidence", "created_at",
           "updated_at")
COLUMN_LIST = ", ".join(f'"{c}"' for c in COLUMNS)
MARK = "bench-map"  # evidence of every synthetic sign: the loader's own rows, nobody else's


@dataclass(frozen=True)
class SyntheticMap:
    n: int
    seed: int
    cities: np.ndarray  # (N_CITIES, 2) lon, lat

    def city_bbox(self, city: int = 0) -> tuple[float, float, float, float]:
        lon, lat = self.cities[city]
        h = CITY_BOX_DEG / 2
        return (lon - h, lat - h, lon + h, lat + h)


def layout(n: int, seed: int = 0) -> SyntheticMap:
    rng = np.random.default_rng(seed)
    lo = np.array(REGION[:2]) + 0.3
    hi = np.array(REGION[2:]) - 0.3
    return SyntheticMap(n, seed, rng.uniform(lo, hi, size=(N_CITIES, 2)))


def rows(m: SyntheticMap, chunk: int = 100_000):
    """The signs as tuples in COLUMNS order, ``chunk`` at a time (ids random, as fusion's are)."""
    rng = np.random.default_rng(m.seed + 1)
    start = datetime(2026, 11, 1, tzinfo=timezone.utc)
    cov = json.dumps([[0.25, 0.0, 0.0], [0.0, 0.25, 0.0], [0.0, 0.0, 1.0]])
    evidence = json.dumps({"synthetic": MARK})
    for first in range(0, m.n, chunk):
        k = min(chunk, m.n - first)
        in_city = rng.random(k) < CITY_SHARE
        city = rng.integers(0, N_CITIES, k)
        lon = np.where(in_city, m.cities[city, 0] + rng.normal(0, CITY_SIGMA_DEG, k),
                       rng.uniform(REGION[0], REGION[2], k))
        lat = np.where(in_city, m.cities[city, 1] + rng.normal(0, CITY_SIGMA_DEG, k),
                       rng.uniform(REGION[1], REGION[3], k))
        ids = rng.integers(0, 2**63, k)
        cls = rng.integers(0, len(CLASSES), k)
        state = rng.choice(3, k, p=(0.8, 0.15, 0.05))
        n_j = rng.integers(1, 9, k)
        days = rng.integers(0, 20, k)
        for i in range(k):
            seen = start + timedelta(days=int(days[i]))
            yield (f"ms-{int(ids[i]):016x}", CLASSES[cls[i]], float(lat[i]), float(lon[i]),
                   None if i % 5 == 0 else 110.0 + i % 40, cov, 0.5, int(n_j[i]), int(n_j[i]),
                   seen, seen, STATES[state[i]], evidence, seen, seen)


def first_id(m: SyntheticMap) -> str:
    return next(rows(m))[0]


def _holds(url: str, m: SyntheticMap) -> bool:
    """The database holds exactly the map of (n, seed); refuses one that holds journeys (a real
    service's database: the loader replaces the whole map)."""
    with session_scope(url) as session:
        if session.scalar(select(func.count()).select_from(JourneyRow)):
            raise ValueError(f"{url.split('@')[-1]} holds journeys: not a bench database")
        return (session.scalar(select(func.count()).select_from(MapSignRow)) == m.n
                and session.get(MapSignRow, first_id(m)) is not None)


def _copy_postgres(url: str, m: SyntheticMap) -> None:
    raw = get_engine(url).raw_connection()
    try:
        with raw.cursor() as cur:
            cur.execute("TRUNCATE map_signs CASCADE")
            with cur.copy(f"COPY map_signs ({COLUMN_LIST}) FROM STDIN") as copy:
                for row in rows(m):
                    copy.write_row(row)
        raw.commit()
    finally:
        raw.close()
    with get_engine(url).connect().execution_options(isolation_level="AUTOCOMMIT") as conn:
        conn.execute(text("VACUUM ANALYZE map_signs"))


def _insert_sqlite(url: str, m: SyntheticMap) -> None:
    raw = get_engine(url).raw_connection()
    try:
        cur = raw.cursor()
        cur.execute("DELETE FROM map_signs")
        insert = f"INSERT INTO map_signs ({COLUMN_LIST}) VALUES ({', '.join('?' * len(COLUMNS))})"
        batch: list[tuple] = []
        for row in rows(m):
            # SQLite stores the naive UTC text the models' UTCDateTime writes.
            batch.append(tuple(v.replace(tzinfo=None) if isinstance(v, datetime) else v
                               for v in row))
            if len(batch) == 50_000:
                cur.executemany(insert, batch)
                batch.clear()
        if batch:
            cur.executemany(insert, batch)
        raw.commit()
        cur.execute("ANALYZE")
        cur.close()
    finally:
        raw.close()


def ensure_loaded(url: str, n: int, seed: int = 0, log=print) -> tuple[SyntheticMap, bool]:
    """Migrate ``url`` and make its map exactly the synthetic one of (n, seed); returns it and
    whether it had to be (re)loaded. A map of another size is replaced."""
    upgrade(url)
    m = layout(n, seed)
    if _holds(url, m):
        return m, False
    log(f"loading {n:,} synthetic map signs into {url.split('@')[-1]} ...")
    if url.startswith("postgresql"):
        _copy_postgres(url, m)
    else:
        _insert_sqlite(url, m)
    return m, True
