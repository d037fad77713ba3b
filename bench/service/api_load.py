"""``signmap bench api``: a bounded load run of the HTTP API on 127.0.0.1.

For each backend (SQLite with the embedded worker; PostgreSQL + Redis + a Celery worker process)
a real `signmap serve` is started on a fresh database holding a seeded map, and concurrent
clients send a fixed number of requests: uploads (a few rendered journeys with a turn that really
get processed, many small straight ones that are accepted and then parked within seconds by the
job, waiting for their camera (no turn, a camera nobody calibrated), and re-uploads of the same bytes), map reads (a street and a city box), journey status polls
and health checks. Then, until every job has ended, the clients keep reading the map. Reported per kind
of request: count, errors (5xx, unexpected status, connection errors), p50/p95/p99/max latency;
and what became of every accepted upload, from the database and the job logs: each must end done,
failed or waiting exactly once (one row, one attempt, one ending), re-uploads must name the same journey.
Then the same clients send N distinct big uploads (40 MB by default) while the worker(s) run their
jobs: uploads accepted per second, MB/s, latency per upload, and the same account of each upload.
"""

from __future__ import annotations

import asyncio
import hashlib
import json
import os
import random
import tempfile
import time
from collections import Counter
from dataclasses import asdict, dataclass
from datetime import date
from pathlib import Path

import httpx
import numpy as np

from app.settings import Settings
from bench.service import api_uploads
from bench.service.api_stack import (CITY, STREET, Service, account, bundles, journey_states,
                                     running_service, variant)
from bench.paper.tables import md_table

BENCH_DIR = Path(__file__).resolve().parents[1]
KINDS = ("upload (new)", "upload (processed)", "upload (same bytes)", "map read (street)",
         "map read (city, 500)", "journey status", "health", "map read (street) while jobs run")


@dataclass
class Options:
    backends: tuple[str, ...] = ("sqlite", "postgres")
    clients: int = 8
    requests: int = 400  # reads, polls and health checks (uploads come on top)
    uploads: int = 16  # new fail-fast uploads; each is also re-uploaded once in 4
    processed: int = 2  # rendered journeys with a turn, really processed
    big_uploads: int = 16  # distinct big fail-fast uploads after the load (0: none)
    big_upload_mb: float = 40.0
    drain_timeout_s: float = 600.0
    map_signs: int = 2000
    seed: int = 0
    postgres_url: str = "postgresql+psycopg://postgres@127.0.0.1:5432/postgres"
    redis_url: str = "redis://127.0.0.1:6379/12"
    out_dir: Path = BENCH_DIR / "results"
    cache_dir: Path = BENCH_DIR / "cache"


QUICK = dict(clients=4, requests=40, uploads=3, processed=0, drain_timeout_s=180.0,
             map_signs=300, big_uploads=4, big_upload_mb=8.0)


@dataclass
class Request:
    kind: str
    method: str
    path: str
    expect: tuple[int, ...]
    payload: bytes | None = None


@dataclass
class Sample:
    kind: str
    seconds: float
    status: int | None
    error: str | None = None
    journey_id: str | None = None


def _box(b: tuple[float, float, float, float]) -> str:
    return ",".join(f"{v:.6f}" for v in b)


def plan(opts: Options, turn: bytes, straight: bytes, rng: random.Random) -> list[Request]:
    """The run's requests, processed uploads first (their jobs then overlap the load)."""
    upload = ("POST", "/api/v1/journeys")
    firsts = [Request("upload (processed)", *upload, (202,), variant(turn, f"bench-turn-{i}"))
              for i in range(opts.processed)]
    news = [Request("upload (new)", *upload, (202,), variant(straight, f"bench-straight-{i}"))
            for i in range(opts.uploads)]
    # A re-upload answers 200 with the journey (202 if it raced the first upload or the journey
    # had failed: a failed journey is queued again, so it must end a second time).
    repeats = [Request("upload (same bytes)", *upload, (200, 202), r.payload)
               for r in news[::4]]
    for r in news[::4]:  # either of the two may arrive first
        r.expect = (200, 202)
    reads = []
    for _ in range(opts.requests):
        x = rng.random()
        if x < 0.4:
            reads.append(Request("map read (street)", "GET",
                                 f"/api/v1/signs?bbox={_box(STREET)}", (200,)))
        elif x < 0.6:
            reads.append(Request("map read (city, 500)", "GET",
                                 f"/api/v1/signs?bbox={_box(CITY)}&limit=500", (200,)))
        elif x < 0.85:
            reads.append(Request("journey status", "GET", "/api/v1/journeys/{id}", (200,)))
        else:
            reads.append(Request("health", "GET", "/api/v1/health", (200,)))
    rest = news + reads
    rng.shuffle(rest)
    # Re-uploads go in the second half, after their first upload was most likely answered.
    half = len(rest) // 2
    tail = rest[half:] + repeats
    rng.shuffle(tail)
    return firsts + rest[:half] + tail


async def _send(client: httpx.AsyncClient, service: Service, req: Request, accepted: list[str],
                rng: random.Random) -> Sample:
    key = service.fleet_key if req.method == "POST" or "journeys" in req.path \
        else service.reader_key
    path = req.path
    if "{id}" in path:
        path = path.replace("{id}", rng.choice(accepted) if accepted else "none-yet")
        req = Request(req.kind, req.method, path, (200,) if accepted else (404,))
    files = {"bundle": ("journey.zip", req.payload, "application/zip")} if req.payload else None
    t0 = time.perf_counter()
    try:
        response = await client.request(req.method, path, files=files,
                                        headers={"Authorization": f"Bearer {key}"})
    except httpx.HTTPError as exc:
        return Sample(req.kind, time.perf_counter() - t0, None, f"{type(exc).__name__}: {exc}")
    seconds = time.perf_counter() - t0
    error = None
    if response.status_code not in req.expect:
        error = f"{response.status_code}: {response.text[:200]}"
    journey_id = response.json().get("id") if req.payload and response.status_code in (200, 202) \
        else None
    if journey_id and response.status_code == 202:
        accepted.append(journey_id)
    return Sample(req.kind, seconds, response.status_code, error, journey_id)


async def load(service: Service, requests: list[Request], clients: int, rng: random.Random
               ) -> tuple[list[Sample], list[Request], float]:
    """Send ``requests`` from ``clients`` concurrent clients; (samples, their requests, seconds)."""
    queue: asyncio.Queue = asyncio.Queue()
    for req in requests:
        queue.put_nowait(req)
    samples: list[tuple[Sample, Request]] = []
    accepted: list[str] = []

    async def client_loop() -> None:
        async with httpx.AsyncClient(base_url=service.base_url, timeout=120) as client:
            while not queue.empty():
                req = queue.get_nowait()
                samples.append((await _send(client, service, req, accepted, rng), req))

    t0 = time.perf_counter()
    await asyncio.gather(*(client_loop() for _ in range(clients)))
    return [s for s, _ in samples], [r for _, r in samples], time.perf_counter() - t0


async def drain(service: Service, accepted: set[str], timeout_s: float, clients: int
                ) -> tuple[list[Sample], float]:
    """Wait until every accepted upload has ended (or ``timeout_s``), ``clients`` readers reading
    the street box meanwhile, each twice a second."""
    t0 = time.monotonic()
    ended = asyncio.Event()
    samples: list[Sample] = []
    headers = {"Authorization": f"Bearer {service.reader_key}"}

    async def watch() -> None:
        while time.monotonic() - t0 < timeout_s:
            states = await asyncio.to_thread(journey_states,
                                             service.settings.effective_database_url, accepted)
            if all(states.get(i) in ("done", "failed", "waiting") for i in accepted):
                break
            await asyncio.sleep(1.0)
        ended.set()

    async def read() -> None:
        async with httpx.AsyncClient(base_url=service.base_url, timeout=60) as client:
            while not ended.is_set():
                s0 = time.perf_counter()
                try:
                    r = await client.get(f"/api/v1/signs?bbox={_box(STREET)}", headers=headers)
                    status, error = r.status_code, None if r.status_code == 200 else r.text[:200]
                except httpx.HTTPError as exc:
                    status, error = None, f"{type(exc).__name__}: {exc}"
                samples.append(Sample(KINDS[-1], time.perf_counter() - s0, status, error))
                await asyncio.sleep(0.5)

    await asyncio.gather(watch(), *(read() for _ in range(clients)))
    return samples, time.monotonic() - t0


def run_big_uploads(service: Service, big: list[bytes], opts: Options) -> dict:
    """Send the ``big`` bundles from ``opts.clients`` clients, wait until their jobs have ended,
    account for them (the worker(s) run each job as soon as its upload is queued)."""
    load_before = os.getloadavg()[0]
    requests = [Request(api_uploads.KIND, "POST", "/api/v1/journeys", (202,), b) for b in big]
    samples, sent, seconds = asyncio.run(load(service, requests, opts.clients,
                                              random.Random(opts.seed)))
    accepted = Counter(s.journey_id for s in samples if s.status == 202 and s.journey_id)
    # No readers (0 clients) while waiting: the figures are the uploads' and their jobs'.
    _, drain_s = asyncio.run(drain(service, set(accepted), opts.drain_timeout_s, 0))
    jobs = account(service, accepted, {})
    log_text = service.logs[0].read_text(errors="replace")
    accepted_bytes = sum(len(r.payload or b"") for s, r in zip(samples, sent)
                         if s.journey_id in accepted)
    return {"mb_each": round(len(big[0]) / api_uploads.MB, 1),
            "frames_each": api_uploads.n_frames(big[0]),
            "stats": api_uploads.summary(
                [s.seconds for s in samples], sum(s.error is not None for s in samples),
                accepted_bytes, len(accepted), seconds,
                api_uploads.validation_s(log_text, set(accepted))),
            "drain_s": round(drain_s, 1), "jobs": jobs,
            "loadavg": [round(load_before, 1), round(os.getloadavg()[0], 1)],
            "errors": [asdict(s) for s in samples if s.error][:20]}


def run_backend(backend: str, opts: Options, turn: bytes, straight: bytes, run_dir: Path,
                big: list[bytes] | None = None) -> dict:
    rng = random.Random(opts.seed)
    load_before = os.getloadavg()[0]
    with running_service(backend, run_dir, opts.postgres_url, opts.redis_url,
                         opts.map_signs) as service:
        requests = plan(opts, turn, straight, rng)
        samples, sent, load_s = asyncio.run(load(service, requests, opts.clients, rng))
        accepted = Counter(s.journey_id for s in samples if s.status == 202 and s.journey_id)
        repeats: dict[str, set[str]] = {}
        for s, req in zip(samples, sent):
            if req.payload is not None and s.journey_id:
                repeats.setdefault(_sha(req.payload), set()).add(s.journey_id)
        drained, drain_s = asyncio.run(drain(service, set(accepted), opts.drain_timeout_s,
                                             opts.clients))
        jobs = account(service, accepted, repeats)
        load_after = os.getloadavg()[0]
        # After the load above has drained, so that its figures stay what they were without it.
        uploads = run_big_uploads(service, big, opts) if big else None
    return {"backend": backend, "load_s": round(load_s, 2),
            "load_rps": round(len(samples) / load_s, 1), "drain_s": round(drain_s, 1),
            # The machine's 1-minute load average before and after: other work skews latency.
            "loadavg": [round(load_before, 1), round(load_after, 1)],
            "stats": stats(samples + drained), "jobs": jobs,
            "errors": [asdict(s) for s in samples + drained if s.error][:20],
            "uploads": uploads}


def _sha(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def stats(samples: list[Sample]) -> dict[str, dict]:
    out = {}
    for kind in KINDS:
        mine = [s for s in samples if s.kind == kind]
        if not mine:
            continue
        ms = np.array([s.seconds * 1000 for s in mine])
        out[kind] = {"n": len(mine), "errors": sum(s.error is not None for s in mine),
                     **{f"p{q}_ms": round(float(np.percentile(ms, q)), 1) for q in (50, 95, 99)},
                     "max_ms": round(float(ms.max()), 1)}
    return out


NAMES = {"sqlite": "SQLite, embedded worker", "postgres": "PostgreSQL + Redis + 1 Celery worker"}


def markdown(report: dict) -> str:
    o = report["options"]
    parts = [f"# API load ({report['date']})", "",
             f"`{report['command']}`: {o['clients']} concurrent clients on 127.0.0.1, "
             f"{o['requests']} reads/polls/health checks, {o['uploads']} fail-fast uploads (+ one "
             f"in 4 re-uploaded), {o['processed']} rendered journeys really processed, a map of "
             f"{o['map_signs']} signs. Latency in ms, whole request (uploads include the "
             f"validation in the API). Machine: 2 cores, shared with other work (load average "
             f"below).", ""]
    for run in report["runs"]:
        rows = [[kind, s["n"], s["errors"], s["p50_ms"], s["p95_ms"], s["p99_ms"], s["max_ms"]]
                for kind, s in run["stats"].items()]
        j = run["jobs"]
        lost = len(j["missing"]) + len(j["unfinished"])
        parts += [f"## {NAMES[run['backend']]}", "",
                  md_table(["request", "n", "errors", "p50", "p95", "p99", "max"], rows), "",
                  f"Load {run['load_s']} s ({run['load_rps']} requests/s), then jobs ran on for "
                  f"{run['drain_s']} s; the machine's load average {run['loadavg'][0]} before, "
                  f"{run['loadavg'][1]} after. Accepted uploads: {j['accepted']} (queued again by a "
                  f"re-upload after failing: {j['requeued_by_reupload']}): done {j['done']} "
                  f"({j['n_signs_done']} signs), failed "
                  f"{j['failed']}, waiting for their camera {j.get('waiting', 0)}, lost {lost}; retried after a lost run (attempts > 1): "
                  f"{len(j['attempts_not_1'])}; "
                  f"not ended exactly once in the job logs: {len(j['ended_not_once'])}; duplicate "
                  f"rows: {j['duplicate_rows']}; re-uploads naming another journey: "
                  f"{len(j['repeats_split'])}. Failure reasons: "
                  + "; ".join(f"{n} x \"{r}\"" for r, n in j["failure_reasons"].items()), ""]
    big = api_uploads.markdown(report["runs"], NAMES, o)
    return "\n".join(parts + ([big] if big else []))


JOB_PROBLEMS = ("missing", "unfinished", "attempts_not_1", "ended_not_once", "sign_rows_mismatch",
                "duplicate_rows", "repeats_split")


def ok(report: dict) -> bool:
    """No request errors and every accepted upload ended exactly once (big uploads too)."""
    parts = list(report["runs"])
    parts += [run["uploads"] for run in report["runs"] if run.get("uploads")]
    return all(not part["errors"] and not any(part["jobs"][k] for k in JOB_PROBLEMS)
               for part in parts)


def run_api_bench(opts: Options, command: str = "signmap bench api") -> tuple[Path, Path, dict]:
    turn, straight = bundles(opts.cache_dir, with_turn=opts.processed > 0)
    big = api_uploads.big_bundles(opts.big_uploads, opts.big_upload_mb, opts.seed) \
        if opts.big_uploads else []
    if big:  # before minutes of load: the services get this environment's limits too
        api_uploads.check_limits(big[0], Settings())
    runs = []
    with tempfile.TemporaryDirectory(prefix="signmap-bench-api-") as tmp:
        for backend in opts.backends:
            runs.append(run_backend(backend, opts, turn, straight, Path(tmp) / backend, big))
    report = {"date": date.today().isoformat(), "command": command, "runs": runs,
              "options": {k: (str(v) if isinstance(v, Path) else v)
                          for k, v in asdict(opts).items()}}
    opts.out_dir.mkdir(parents=True, exist_ok=True)
    md, js = (opts.out_dir / f"{report['date']}-api.{ext}" for ext in ("md", "json"))
    md.write_text(markdown(report) + "\n")
    js.write_text(json.dumps(report, indent=1) + "\n")
    return md, js, report


ARGS = ("clients", "requests", "uploads", "processed", "big_uploads", "big_upload_mb")


def run_command(args) -> int:
    values = dict(QUICK) if args.quick else {}
    for name in ARGS:
        if getattr(args, name) is not None:
            values[name] = getattr(args, name)
    backends = ("sqlite", "postgres") if args.backend == "both" else (args.backend,)
    opts = Options(backends=backends, out_dir=args.out, cache_dir=args.cache,
                   postgres_url=args.postgres_url, redis_url=args.redis_url, **values)
    given = [f"--{name.replace('_', '-')} {getattr(args, name)}" for name in ARGS
             if getattr(args, name) is not None]
    command = " ".join(["signmap bench api", f"--backend {args.backend}",
                        *(["--quick"] if args.quick else []), *given])
    md, js, report = run_api_bench(opts, command)
    print(md.read_text())
    print(f"wrote {md} and {js}")
    return 0 if ok(report) else 1


def add_parser(bench_sub) -> None:
    p = bench_sub.add_parser(
        "api", help="load run of the HTTP API: latency, errors, no upload lost",
        description=__doc__.split("\n\n", 1)[1].replace("\n", " ").strip() +
        " Exits 1 if any request failed or any accepted upload did not end exactly once.")
    p.add_argument("--backend", choices=("sqlite", "postgres", "both"), default="both",
                   help="which stack to run (default: %(default)s)")
    p.add_argument("--clients", type=int, help="concurrent clients (default 8; quick 4)")
    p.add_argument("--requests", type=int,
                   help="reads, status polls and health checks (default 400; quick 40)")
    p.add_argument("--uploads", type=int,
                   help="new uploads that the job parks within seconds, waiting for their camera "
                        "(default 16; quick 3)")
    p.add_argument("--processed", type=int,
                   help="rendered journeys with a turn, really processed (default 2; quick 0)")
    p.add_argument("--big-uploads", type=int,
                   help="distinct big uploads sent after the load, for upload throughput "
                        "(default 16; quick 4; 0: none)")
    p.add_argument("--big-upload-mb", type=float,
                   help="size of each big upload in MB (default 40; quick 8)")
    p.add_argument("--quick", action="store_true", help="a smoke run of a minute or so")
    p.add_argument("--postgres-url", default=Options.postgres_url,
                   help="PostgreSQL to create the run's database in (default: %(default)s)")
    p.add_argument("--redis-url", default=Options.redis_url,
                   help="Redis for the Celery queue (default: %(default)s)")
    p.add_argument("--out", type=Path, default=BENCH_DIR / "results",
                   help="where <date>-api.md and .json go (default: bench/results)")
    p.add_argument("--cache", type=Path, default=BENCH_DIR / "cache",
                   help="rendered journeys, reused between runs (default: bench/cache)")
    p.set_defaults(func=run_command)
