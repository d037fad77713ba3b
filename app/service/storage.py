"""Where the service keeps files.

Accepted bundles (content-addressed by SHA-256, shared by owners uploading the same bytes) live in a
``BundleStore``: ``data_dir/bundles/<sha256>.zip`` by default (``LocalBundleStore``), or an
S3-compatible object store when ``SIGNMAP_STORAGE_URL=s3://bucket/prefix`` (``S3BundleStore``,
endpoint and credentials from the standard ``AWS_*`` variables), so that the API and the workers
share no filesystem. Everything else under ``data_dir`` is the host's own scratch:

``incoming/``             uploads being received and validated; never read by a job
``work/<journey>-<n>/``   one run's fetched and extracted bundle and pipeline files, deleted at its end
"""

from __future__ import annotations

import logging
import os
import uuid
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator, Protocol
from urllib.parse import urlsplit

from app.settings import Settings

log = logging.getLogger(__name__)


class StorageError(Exception):
    """A bundle could not be stored or read; the message names the bundle and why."""


class StorageUnavailable(StorageError):
    """The object store did not answer or refused the request (an outage or a misconfiguration)."""


class BundleMissing(StorageError):
    """No bundle is stored under that SHA-256."""


class BundleStore(Protocol):
    def put(self, sha256: str, local: Path) -> bool:
        """Store the file ``local`` (which the caller removes afterwards, if it still exists) under
        ``sha256``; True when it was not stored before."""

    def fetch(self, sha256: str, scratch: Path) -> Path:
        """A local, readable path of the bundle; a copy is made under ``scratch`` when needed."""

    def exists(self, sha256: str) -> bool: ...

    def delete(self, sha256: str) -> None: ...


def bundle_path(data_dir: Path, sha256: str) -> Path:
    return data_dir / "bundles" / f"{sha256}.zip"


def incoming_path(data_dir: Path, suffix: str = ".zip") -> Path:
    """A fresh, unique path for an upload in progress (its directory exists)."""
    directory = data_dir / "incoming"
    directory.mkdir(parents=True, exist_ok=True)
    return directory / f"{uuid.uuid4().hex}{suffix}"


def work_dir(data_dir: Path, journey_id: str, attempt: int) -> Path:
    return data_dir / "work" / f"{journey_id}-{attempt}"


class LocalBundleStore:
    """``data_dir/bundles/``: every process that reads bundles must see this directory."""

    def __init__(self, data_dir: Path):
        self.data_dir = data_dir

    def put(self, sha256: str, local: Path) -> bool:
        target = bundle_path(self.data_dir, sha256)
        target.parent.mkdir(parents=True, exist_ok=True)
        existed = target.exists()
        # Same name => same bytes, so replacing an existing copy is harmless and atomic.
        os.replace(local, target)
        return not existed

    def fetch(self, sha256: str, scratch: Path) -> Path:
        path = bundle_path(self.data_dir, sha256)
        if not path.is_file():
            raise BundleMissing(f"the stored bundle {path} is missing on this host")
        return path  # no copy: it is already on this host, and it is never modified

    def exists(self, sha256: str) -> bool:
        return bundle_path(self.data_dir, sha256).is_file()

    def delete(self, sha256: str) -> None:
        bundle_path(self.data_dir, sha256).unlink(missing_ok=True)


class S3BundleStore:
    """``s3://bucket/prefix``: objects ``<prefix>/<sha256>.zip`` in any S3-compatible store."""

    def __init__(self, url: str):
        import boto3
        from botocore.config import Config

        parts = urlsplit(url)
        self.bucket, self.prefix = parts.netloc, parts.path.strip("/")
        # Fail an unreachable store within seconds (an upload then answers 503), not minutes.
        # Path-style addresses: a self-hosted store (MinIO at http://minio:9000) has no DNS name
        # per bucket, and AWS S3 answers path-style requests too.
        config = Config(connect_timeout=5, read_timeout=60, s3={"addressing_style": "path"},
                        retries={"max_attempts": 3, "mode": "standard"})
        # Endpoint, credentials and region come from AWS_ENDPOINT_URL, AWS_ACCESS_KEY_ID, ...
        self.client = boto3.session.Session().client("s3", config=config)

    def key(self, sha256: str) -> str:
        return f"{self.prefix}/{sha256}.zip" if self.prefix else f"{sha256}.zip"

    def _where(self, sha256: str) -> str:
        return f"s3://{self.bucket}/{self.key(sha256)}"

    def put(self, sha256: str, local: Path) -> bool:
        if self.exists(sha256):  # content-addressed: the same name holds the same bytes
            return False
        with _store_errors(f"storing the bundle at {self._where(sha256)}"):
            # Multipart for large files, read from disk part by part: never all in memory.
            self.client.upload_file(str(local), self.bucket, self.key(sha256))
        return True

    def fetch(self, sha256: str, scratch: Path) -> Path:
        dest = scratch / f"{sha256}.zip"
        if dest.is_file():  # fetched before (download_file renames a complete file into place)
            os.utime(dest)
            return dest
        scratch.mkdir(parents=True, exist_ok=True)
        with _store_errors(f"fetching the bundle {self._where(sha256)}"):
            try:
                self.client.download_file(self.bucket, self.key(sha256), str(dest))
            except Exception as exc:
                if _not_found(exc):
                    raise BundleMissing(f"the stored bundle {self._where(sha256)} is missing "
                                        f"from the object store") from exc
                raise
        return dest

    def exists(self, sha256: str) -> bool:
        with _store_errors(f"looking up the bundle {self._where(sha256)}"):
            try:
                self.client.head_object(Bucket=self.bucket, Key=self.key(sha256))
            except Exception as exc:
                if _not_found(exc):
                    return False
                raise
        return True

    def delete(self, sha256: str) -> None:
        with _store_errors(f"deleting the bundle {self._where(sha256)}"):
            self.client.delete_object(Bucket=self.bucket, Key=self.key(sha256))


def _not_found(exc: Exception) -> bool:
    from botocore.exceptions import ClientError

    return isinstance(exc, ClientError) and \
        exc.response.get("Error", {}).get("Code") in ("404", "NoSuchKey", "NotFound")


@contextmanager
def _store_errors(doing: str) -> Iterator[None]:
    """Turns the S3 client's errors into ``StorageUnavailable`` naming what was being done."""
    from boto3.exceptions import Boto3Error
    from botocore.exceptions import BotoCoreError, ClientError

    try:
        yield
    except (BotoCoreError, ClientError, Boto3Error) as exc:
        raise StorageUnavailable(f"the object store failed {doing}: {exc}") from exc


def make_store(settings: Settings) -> BundleStore:
    """The bundle store that ``settings.storage_url`` names (unset: ``data_dir/bundles``)."""
    if settings.storage_url:
        return S3BundleStore(settings.storage_url)
    return LocalBundleStore(settings.data_dir)


def release_bundle(url: str, store: BundleStore, sha256: str) -> None:
    """Delete the stored bundle ``sha256`` once no journey refers to it (deduplicated bytes are
    shared by owners). A store that fails is logged: the journey is gone either way."""
    from sqlalchemy import func, select

    from app.service.db.session import session_scope
    from app.service.db.models import JourneyRow

    with session_scope(url) as session:
        others = session.scalar(select(func.count()).select_from(JourneyRow)
                                .where(JourneyRow.bundle_sha256 == sha256))
    if others:
        return
    try:
        store.delete(sha256)
    except StorageError:
        log.exception("bundle %s: no journey refers to it, but it could not be deleted", sha256)
