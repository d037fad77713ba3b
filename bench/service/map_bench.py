"""``signmap bench map``: load the synthetic maps (cached between runs), run the scenarios of
``bench.service.map_load`` on PostgreSQL and SQLite, write ``<date>-map[-quick].md`` and
``.json``."""

from __future__ import annotations

import json
import os
import time
from dataclasses import dataclass
from datetime import date
from pathlib import Path

from sqlalchemy import create_engine, text
from sqlalchemy.engine import make_url

from bench.service.map_data import ensure_loaded, layout
from bench.service.map_load import SCENARIOS, new_key, run_scenarios, serve

QUICK_SIGNS = 3000


@dataclass(frozen=True)
class MapBenchOptions:
    signs: int = 1_000_000
    sqlite_signs: int = 100_000
    postgres_url: str | None = "postgresql+psycopg://postgres@127.0.0.1:5432/postgres"
    concurrency: tuple[int, ...] = (1, 2, 8)
    scenarios: tuple[str, ...] = SCENARIOS
    requests: int = 400
    quick: bool = False
    cache_dir: Path = Path("bench/cache")
    out_dir: Path = Path("bench/results")
    base_url: str | None = None  # measure a server already running (with --key) instead
    key: str | None = None


def postgres_database(admin_url: str, n: int) -> str:
    """The URL of ``signmap_bench_map_<n>`` next to ``admin_url``'s database, created if missing:
    one database per size, so a quick run never replaces the million-sign one."""
    name = f"signmap_bench_map_{n}"
    admin = create_engine(admin_url, isolation_level="AUTOCOMMIT")
    try:
        with admin.connect() as conn:
            if not conn.scalar(text("SELECT 1 FROM pg_database WHERE datname = :n"), {"n": name}):
                conn.execute(text(f'CREATE DATABASE "{name}"'))
    finally:
        admin.dispose()
    return make_url(admin_url).set(database=name).render_as_string(hide_password=False)


def _measure(label: str, url: str, n: int, opts: MapBenchOptions, log) -> dict:
    t0 = time.perf_counter()
    m, loaded = ensure_loaded(url, n, log=log)
    load_s = time.perf_counter() - t0
    log(f"{label}: {n:,} signs {'loaded' if loaded else 'reused'} in {load_s:.1f} s")
    key = new_key()
    with serve(url, key) as base:
        rows = _rows(base, key, m, opts)
    return {"database": label, "signs": n, "loaded": loaded, "load_s": round(load_s, 1),
            "rows": rows}


def _rows(base: str, key: str, m, opts: MapBenchOptions) -> list[dict]:
    rows = []
    for concurrency in opts.concurrency:
        for timed in run_scenarios(base, key, m, concurrency, opts.requests, opts.scenarios):
            rows.append({**timed.row(), "concurrency": concurrency})
    return rows


def _markdown(runs: list[dict], opts: MapBenchOptions, command: str) -> str:
    lines = [f"# Map at scale ({date.today().isoformat()})", "",
             f"`{command}` on {os.cpu_count()} cores, load average "
             f"{os.getloadavg()[0]:.2f} at the end; a real `signmap serve` (one uvicorn process, "
             f"no worker) on 127.0.0.1; {opts.requests} requests per scenario with C clients at "
             "once (the `C` column); `/health` polled every 0.1 s during each scenario. Latency "
             "is until the whole body is read. Indented rows split the row above by zoom.", ""]
    for run in runs:
        lines += [f"## {run['database']}, {run['signs']:,} signs "
                  f"({'loaded' if run['loaded'] else 'cached database'}"
                  f"{', %.0f s' % run['load_s'] if run['loaded'] else ''})", "",
                  "| C | scenario | requests | errors | p50 ms | p95 ms | p99 ms | max ms | req/s |",
                  "| ---: | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |"]
        for r in run["rows"]:
            rate = r["req_per_s"] or "-"
            scenario = r["scenario"].replace("  ", "&nbsp;&nbsp;")
            lines.append(f"| {r['concurrency']} | {scenario} | {r['requests']} | {r['errors']} | "
                         f"{r['p50_ms']} | {r['p95_ms']} | {r['p99_ms']} | {r['max_ms']} | "
                         f"{rate} |")
        notes = [f"C={r['concurrency']}, {r['scenario']}: {r['note']}" for r in run["rows"]
                 if r["note"]]
        lines += ["", *(f"- {n}" for n in notes), ""]
    return "\n".join(lines)


def run_map_bench(opts: MapBenchOptions, command: str = "signmap bench map", log=print
                  ) -> tuple[Path, Path, list[dict]]:
    runs = []
    if opts.base_url:
        if not opts.key:
            raise ValueError("--base-url needs --key")
        m = layout(opts.signs)
        rows = _rows(opts.base_url, opts.key, m, opts)
        runs.append({"database": f"server at {opts.base_url}", "signs": opts.signs,
                     "loaded": False, "load_s": 0, "rows": rows})
    if not opts.base_url and opts.postgres_url and opts.signs:
        url = postgres_database(opts.postgres_url, opts.signs)
        runs.append(_measure("PostgreSQL", url, opts.signs, opts, log))
    if not opts.base_url and opts.sqlite_signs:
        opts.cache_dir.mkdir(parents=True, exist_ok=True)
        url = f"sqlite:///{(opts.cache_dir / f'map-{opts.sqlite_signs}.db').resolve()}"
        runs.append(_measure("SQLite", url, opts.sqlite_signs, opts, log))
    opts.out_dir.mkdir(parents=True, exist_ok=True)
    stem = f"{date.today().isoformat()}-map{'-quick' if opts.quick else ''}"
    md, js = opts.out_dir / f"{stem}.md", opts.out_dir / f"{stem}.json"
    md.write_text(_markdown(runs, opts, command))
    js.write_text(json.dumps(runs, indent=1))
    return md, js, runs
