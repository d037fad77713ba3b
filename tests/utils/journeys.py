"""Rendered synthetic journeys for the tests, made once per session (or cached on disk).

Under pytest-xdist (``scripts/test.sh`` runs the suite in one worker per core) the workers share
one cache, the parent of their own temporary directories, and a file lock makes one of them render
a journey while the others wait for it instead of rendering it again."""

from __future__ import annotations

import fcntl
import json
import os
from pathlib import Path


def synthetic_journey(tmp_path_factory, name: str, **config) -> tuple[Path, dict]:
    """Render a synthetic journey once per session (or reuse SIGNMAP_TEST_SYNTH_CACHE/<hash>)."""
    import hashlib

    from app.synth.journey import GENERATOR_VERSION, SynthConfig, write_bundle

    cfg = SynthConfig(**config)
    cache = os.environ.get("SIGNMAP_TEST_SYNTH_CACHE")
    base = tmp_path_factory.getbasetemp()
    root = Path(cache) if cache else (base.parent if os.environ.get("PYTEST_XDIST_WORKER")
                                      else base) / "synth"
    digest = hashlib.sha256(repr((GENERATOR_VERSION, cfg)).encode()).hexdigest()[:12]
    out = root / f"{name}-{digest}"
    root.mkdir(parents=True, exist_ok=True)
    with open(root / f"{name}-{digest}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not (out / "truth.json").exists():
            write_bundle(cfg, out)
    return out / "bundle.zip", json.loads((out / "truth.json").read_text())
