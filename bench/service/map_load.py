"""``signmap bench map``: the map API under a bounded concurrent client on 127.0.0.1, over a
synthetic map of N signs (``bench.service.map_data``), on PostgreSQL and SQLite. Each scenario
sends R requests with C at a time to a real ``signmap serve`` and times each until its body is
read; ``/health`` is polled all along to show whether map reads starve the rest of the API
(issue 13, finding 7)."""

from __future__ import annotations

import asyncio
import math
import os
import secrets
import statistics
import tempfile
import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator

import httpx
import numpy as np

from bench.service.map_data import CITY_SIGMA_DEG, N_CITIES, SyntheticMap
from bench.service.serve import serve as bench_serve

REPO = Path(__file__).resolve().parents[2]
HEALTH_EVERY_S = 0.1


@dataclass
class Timings:
    name: str
    latencies_s: list[float] = field(default_factory=list)
    paths: list[str] = field(default_factory=list)  # what each latency was of
    errors: int = 0
    wall_s: float = 0.0
    note: str = ""

    def row(self) -> dict:
        ms = sorted(1000 * v for v in self.latencies_s) or [math.nan]
        pick = lambda q: ms[min(len(ms) - 1, int(math.ceil(q * len(ms))) - 1)]  # noqa: E731
        return {"scenario": self.name, "requests": len(self.latencies_s), "errors": self.errors,
                "p50_ms": round(statistics.median(ms), 1), "p95_ms": round(pick(0.95), 1),
                "p99_ms": round(pick(0.99), 1), "max_ms": round(ms[-1], 1),
                "req_per_s": round(len(self.latencies_s) / self.wall_s, 1) if self.wall_s else 0,
                "note": self.note}


@contextmanager
def serve(database_url: str, admin_key: str, env_extra: dict | None = None) -> Iterator[str]:
    """A real ``signmap serve`` on a free port of 127.0.0.1 (no worker); yields its base URL."""
    with tempfile.TemporaryDirectory(prefix="signmap-bench-map-") as tmp:
        env = {k: v for k, v in os.environ.items() if not k.startswith("SIGNMAP_")}
        env.update(SIGNMAP_DATA_DIR=tmp, SIGNMAP_DATABASE_URL=database_url,
                   SIGNMAP_ADMIN_KEY=admin_key, SIGNMAP_EMBEDDED_WORKER="false",
                   SIGNMAP_LOG_LEVEL="WARNING", PYTHONPATH=str(REPO), **(env_extra or {}))
        with bench_serve(env, Path(tmp) / "serve.log") as base:
            yield base


def tile_of(lon: float, lat: float, z: int) -> tuple[int, int, int]:
    n = 2 ** z
    x = int((lon + 180.0) / 360.0 * n)
    y = int((1.0 - math.asinh(math.tan(math.radians(lat))) / math.pi) / 2.0 * n)
    return z, min(max(x, 0), n - 1), min(max(y, 0), n - 1)


def tile_paths(m: SyntheticMap, zooms: range, n: int, seed: int = 7) -> list[str]:
    """Tiles where map readers look: around the cities' signs, at the given zooms."""
    rng = np.random.default_rng(seed)
    paths = []
    for _ in range(n):
        lon, lat = m.cities[rng.integers(N_CITIES)] + rng.normal(0, CITY_SIGMA_DEG, 2)
        z, x, y = tile_of(float(lon), float(lat), int(rng.choice(list(zooms))))
        paths.append(f"/api/v1/tiles/{z}/{x}/{y}.mvt")
    return paths


def _next_of(body: bytes) -> str | None:
    # The page's last member; parsing a thousand features just for it would load the client.
    tail = body[body.rfind(b'"next":') + 7:].rstrip(b"} \n")
    return None if tail == b"null" else tail.strip(b'"').decode()


async def _health(client: httpx.AsyncClient, stop: asyncio.Event, into: Timings) -> None:
    while not stop.is_set():
        t0 = time.perf_counter()
        try:
            ok = (await client.get("/api/v1/health")).status_code == 200
        except httpx.HTTPError:
            ok = False
        into.latencies_s.append(time.perf_counter() - t0)
        into.errors += not ok
        try:
            await asyncio.wait_for(stop.wait(), HEALTH_EVERY_S)
        except asyncio.TimeoutError:
            pass


async def _run(base: str, key: str, concurrency: int, n_requests: int, name: str,
               next_path, health: Timings | None) -> Timings:
    """``n_requests`` GETs of ``next_path(worker, previous body)``, ``concurrency`` at a time."""
    out = Timings(name)
    left = [n_requests]
    limits = httpx.Limits(max_connections=concurrency + 2)
    async with httpx.AsyncClient(base_url=base, headers={"Authorization": f"Bearer {key}"},
                                 timeout=120, limits=limits) as client:
        stop = asyncio.Event()
        probe = asyncio.create_task(_health(client, stop, health)) if health else None

        async def worker(w: int) -> None:
            body = None
            while left[0] > 0:
                left[0] -= 1
                path = next_path(w, body)
                t0 = time.perf_counter()
                try:
                    answer = await client.get(path)
                    body = answer.content
                    ok = answer.status_code == 200
                except httpx.HTTPError:
                    body, ok = None, False
                out.latencies_s.append(time.perf_counter() - t0)
                out.paths.append(path)
                out.errors += not ok
                if not ok:
                    body = None

        t0 = time.perf_counter()
        await asyncio.gather(*(worker(w) for w in range(concurrency)))
        out.wall_s = time.perf_counter() - t0
        stop.set()
        if probe:
            await probe
    return out


def bbox_walker(m: SyntheticMap, limit: int):
    """Each client walks one city's box page by page along ``next``, then starts the next city."""
    state: dict[int, tuple[int, int]] = {}  # worker -> (city, pages read in this walk)
    depth: list[int] = []

    def next_path(w: int, body: bytes | None) -> str:
        city, pages = state.get(w, (w % N_CITIES, 0))
        cursor = _next_of(body) if body is not None and pages else None
        if pages and cursor is None:  # the walk ended (or failed): the next city, from the top
            depth.append(pages)
            city, pages = (city + 1) % N_CITIES, 0
        state[w] = (city, pages + 1)
        bbox = ",".join(f"{v:.6f}" for v in m.city_bbox(city))
        return (f"/api/v1/signs?bbox={bbox}&limit={limit}"
                + (f"&cursor={cursor}" if cursor else ""))
    return next_path, depth


SCENARIOS = ("pages", "big-pages", "tiles", "low-tiles")


def _by_zoom(timed: Timings) -> list[Timings]:
    """The tile scenario's requests split by zoom."""
    zooms: dict[int, Timings] = {}
    for path, latency in zip(timed.paths, timed.latencies_s):
        z = int(path.split("/")[4])
        zooms.setdefault(z, Timings(f"  tiles z{z}", wall_s=0.0)).latencies_s.append(latency)
    return [zooms[z] for z in sorted(zooms)]


def run_scenarios(base: str, key: str, m: SyntheticMap, concurrency: int, n_requests: int,
                  scenarios: tuple[str, ...] = SCENARIOS) -> list[Timings]:
    results: list[Timings] = []

    def one(name: str, next_path) -> Timings:
        health = Timings(f"/health during: {name}")
        timed = asyncio.run(_run(base, key, concurrency, n_requests, name, next_path, health))
        results.extend([timed, health])
        return timed

    if "pages" in scenarios:
        walk, depth = bbox_walker(m, 1000)
        timed = one("bbox city, limit=1000, following next", walk)
        timed.note = (f"{len(depth)} walks through a city box finished, pages per walk: "
                      f"{min(depth) if depth else '-'}..{max(depth) if depth else '-'}")
    if "big-pages" in scenarios:
        one("bbox city, limit=10000 (capped by SIGNMAP_MAP_PAGE_MAX)", bbox_walker(m, 10000)[0])
    for scenario, zooms, name in (("tiles", range(12, 17), "tiles z12-16"),
                                  ("low-tiles", range(6, 12), "tiles z6-11")):
        if scenario not in scenarios:
            continue
        paths = tile_paths(m, zooms, n_requests)
        timed = one(name, lambda w, body, it=iter(paths): next(it))
        timed.note = (f"{len(set(paths))} distinct tiles; the server caches those at z <= 11 "
                      "(SIGNMAP_TILE_CACHE_MAX_ZOOM) after their first request")
        results[-1:-1] = _by_zoom(timed)  # before its /health row
    return results


def new_key() -> str:
    return "bench-map-" + secrets.token_hex(12)
