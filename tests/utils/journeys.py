"""Rendered synthetic journeys for the tests, made once per session (or cached on disk)."""

from __future__ import annotations

import json
import os
from pathlib import Path


def synthetic_journey(tmp_path_factory, name: str, **config) -> tuple[Path, dict]:
    """Render a synthetic journey once per session (or reuse SIGNMAP_TEST_SYNTH_CACHE/<hash>)."""
    import hashlib

    from app.synth.journey import GENERATOR_VERSION, SynthConfig, write_bundle

    cfg = SynthConfig(**config)
    cache = os.environ.get("SIGNMAP_TEST_SYNTH_CACHE")
    root = Path(cache) if cache else tmp_path_factory.getbasetemp() / "synth"
    digest = hashlib.sha256(repr((GENERATOR_VERSION, cfg)).encode()).hexdigest()[:12]
    out = root / f"{name}-{digest}"
    if not (out / "truth.json").exists():
        write_bundle(cfg, out)
    return out / "bundle.zip", json.loads((out / "truth.json").read_text())
