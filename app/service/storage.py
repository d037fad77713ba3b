"""Where the service keeps files under ``data_dir``; the API and every worker must share it.

``bundles/<sha256>.zip``  accepted uploads, content-addressed (shared by owners uploading the same bytes)
``incoming/``             uploads being received and validated; never read by a job
``work/<journey>-<n>/``   one run's extracted bundle and pipeline files, deleted when the run ends
"""

from __future__ import annotations

import os
import uuid
from pathlib import Path


def bundle_path(data_dir: Path, sha256: str) -> Path:
    return data_dir / "bundles" / f"{sha256}.zip"


def incoming_path(data_dir: Path, suffix: str = ".zip") -> Path:
    """A fresh, unique path for an upload in progress (its directory exists)."""
    directory = data_dir / "incoming"
    directory.mkdir(parents=True, exist_ok=True)
    return directory / f"{uuid.uuid4().hex}{suffix}"


def work_dir(data_dir: Path, journey_id: str, attempt: int) -> Path:
    return data_dir / "work" / f"{journey_id}-{attempt}"


def keep_bundle(data_dir: Path, incoming: Path, sha256: str) -> tuple[Path, bool]:
    """Move a validated upload to its content address; returns (path, whether it is new there)."""
    target = bundle_path(data_dir, sha256)
    target.parent.mkdir(parents=True, exist_ok=True)
    existed = target.exists()
    # Same name => same bytes, so replacing an existing copy is harmless and atomic.
    os.replace(incoming, target)
    return target, not existed
