"""What each hostile upload of the bad-input corpus costs the API process (issue 13, findings 1-3).

Run from a checkout (it builds the uploads with ``tests/utils/hostile_bundles.py``)::

    PYTHONPATH=$PWD python -m bench.service.hostile_uploads [--code DIR] [CASE ...]

Each case is POSTed once to a fresh app (SQLite, no worker) in its own Python process, whose
code comes from ``--code`` (default: this checkout; point it at an export of an older commit to
measure "before"). Printed per case: status, wall time of the request, the process's resident memory
before the request and at its peak, the bytes it wrote while answering (``/proc/self/io`` wchar:
the upload itself plus whatever was unpacked), and the start of the ``detail``.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

_CHILD = r"""
import json, resource, sys, tempfile, time
from fastapi.testclient import TestClient
from app.commands.service import create_service_app
from app.service.auth import create_key
from app.service.db.session import session_scope, upgrade
from app.settings import Settings

def rss_mb():
    for line in open("/proc/self/status"):
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024

def wchar():
    for line in open("/proc/self/io"):
        if line.startswith("wchar:"):
            return int(line.split()[1])

settings = Settings(data_dir=tempfile.mkdtemp(), embedded_worker=False, admin_key="bench-admin")
upgrade(settings.effective_database_url)
with session_scope(settings.effective_database_url) as session:
    key = create_key(session, "fleet", "bench")
data = open(sys.argv[1], "rb").read()
with TestClient(create_service_app(settings)) as client:
    client.get("/api/v1/health")
    before_mb, written0 = rss_mb(), wchar()
    t0 = time.perf_counter()
    response = client.post("/api/v1/journeys", headers={"Authorization": f"Bearer {key}"},
                           files={"bundle": ("journey.zip", data, "application/zip")})
    seconds = time.perf_counter() - t0
    written = wchar() - written0
peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
body = response.json()
print(json.dumps({"status": response.status_code, "seconds": round(seconds, 2),
                  "rss_before_mb": round(before_mb), "rss_peak_mb": round(peak_mb),
                  "written_mb": round(written / 2**20, 1),
                  "detail": str(body.get("detail", body.get("status")))[:90]}))
"""


def _cases() -> dict:
    from tests.utils import hostile_bundles as hb

    return {
        "1M detection rows": hb.million_detection_rows,
        "3 frames x 1000 unlabelled boxes": hb.thousand_boxes_per_frame,
        "8 frames padded to 250 MiB, bad GPS": hb.padded_frames,
        "PNG header 20000x20000": hb.png_header_claiming_20000,
        "JPEG header 65000x65000": hb.jpeg_header_claiming_65000,
        "3 real 8192x8192 frames": hb.real_8192_frames,
        # What an accepted upload may now cost at most (the defaults' limits).
        "300,000 detection rows (the limit)": lambda: hb.detection_rows(300_000),
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--code", type=Path, default=Path.cwd(),
                        help="checkout whose app/ answers the uploads (default: this one)")
    parser.add_argument("cases", nargs="*", help="case names (default: all)")
    args = parser.parse_args(argv)
    cases = _cases()
    chosen = args.cases or list(cases)
    env = {**os.environ, "PYTHONPATH": str(args.code.resolve())}
    with tempfile.TemporaryDirectory() as tmp:
        for name in chosen:
            data = cases[name]()
            path = Path(tmp) / "upload.zip"
            path.write_bytes(data)
            run = subprocess.run([sys.executable, "-c", _CHILD, str(path)], env=env,
                                 capture_output=True, text=True, cwd=tmp)
            if run.returncode:
                print(f"{name}: child failed:\n{run.stderr[-2000:]}")
                continue
            result = json.loads(run.stdout.strip().splitlines()[-1])
            print(f"{name} ({len(data) / 1e6:.2f} MB): {result['status']} in "
                  f"{result['seconds']} s, RSS {result['rss_before_mb']} -> "
                  f"{result['rss_peak_mb']} MB, wrote {result['written_mb']} MB; "
                  f"{result['detail']}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
