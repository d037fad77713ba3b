"""The one configuration object of Signmap, read from ``SIGNMAP_*`` environment variables."""

from __future__ import annotations

from functools import cached_property
from pathlib import Path
from urllib.parse import urlsplit

from pydantic import BaseModel, Field, field_validator
from pydantic_settings import BaseSettings, SettingsConfigDict

from app.fusion.config import FusionConfig
from app.pipeline.config import BundleLimits, PipelineConfig
from app.pipeline.detect.model import DetectorConfig


class Settings(BaseSettings):
    model_config = SettingsConfigDict(env_prefix="SIGNMAP_", env_nested_delimiter="__")

    data_dir: Path = Path("./signmap-data")
    database_url: str | None = Field(None, description="default: SQLite file under data_dir")
    broker_url: str | None = Field(None, description="default: none, an in-process worker runs jobs")
    storage_url: str | None = Field(
        None, description="where accepted bundles are kept: unset = data_dir/bundles (the API and "
                          "workers then share data_dir); s3://bucket/prefix = an S3-compatible "
                          "store, endpoint and credentials from AWS_ENDPOINT_URL, "
                          "AWS_ACCESS_KEY_ID, AWS_SECRET_ACCESS_KEY")
    admin_key: str | None = None
    max_upload_mb: int = 2048
    # Uploads per key (docs/decisions/upload-rate-limit.md): checking a bundle costs the API CPU, so
    # one key cannot keep it busy; a fleet's vehicles uploading each journey stay far below.
    upload_limit_count_per_min: int = Field(
        30, ge=0, description="uploads one API key may make in a sliding minute (counted before "
                              "the bundle is checked, so refused ones count); past it, 429 with "
                              "Retry-After; 0 = no limit")
    upload_limit_bytes_per_min: int = Field(
        2 * 2**30, ge=0, description="bytes one API key may upload in a sliding minute; past it, "
                                     "429 with Retry-After; 0 = no limit")
    bundle: BundleLimits = Field(
        BundleLimits(), description="what one bundle may unpack to and contain (rows, frames, "
        "pixels), checked before the work is spent; SIGNMAP_BUNDLE__<NAME>")
    log_level: str = "INFO"
    # Admin dashboard (docs/service.md, "Dashboard").
    map_tile_url: str = Field(
        "https://tile.openstreetmap.org/{z}/{x}/{y}.png",
        description="base map tiles of the dashboard; without them signs show on a plain background")
    admin_session_max_age_s: int = Field(12 * 3600, description="dashboard sign-in lifetime")
    # Key guessing (see docs/service.md, "Keys and roles").
    auth_failure_limit: int = Field(
        10, ge=1, description="failed dashboard sign-ins and unknown Bearer keys one client "
                              "address may make within auth_failure_window_s; past it, 429")
    auth_failure_window_s: float = Field(
        60.0, gt=0, description="how long a failed sign-in or unknown key counts against its "
                                "client address")

    # Leftovers of crashes (see docs/service.md, "Jobs and recovery").
    incoming_max_age_s: float = Field(
        3600.0, description="an upload in incoming/ untouched this long was left by a dead API "
                            "process and is deleted; longer than any live upload takes")
    sweep_interval_s: float = Field(
        300.0, description="how often the API sweeps orphaned uploads and expired sign-ins")

    # Jobs (see docs/service.md, "Jobs and recovery").
    embedded_worker: bool = Field(
        True, description="without a broker, run jobs in the API process; off = uploads stay queued")
    celery_queue: str = Field("signmap", description="Celery queue the API sends journeys to")
    heartbeat_s: float = Field(10.0, description="how often a running job stamps its heartbeat")
    stale_after_s: float = Field(
        120.0, description="a running job whose heartbeat is older than this is requeued")
    max_attempts: int = Field(3, description="runs of one journey before it is marked failed")
    broker_visibility_timeout_s: int = Field(
        6 * 3600, description="Redis redelivers an unacknowledged job after this; longer than a job")
    pipeline: PipelineConfig = PipelineConfig()
    # Sign detector for bundles without detections.csv (SIGNMAP_DETECTOR__MODEL=/path/model.onnx).
    detector: DetectorConfig = DetectorConfig()

    # Map fusion (see docs/service.md, "Map fusion").
    fusion: FusionConfig = FusionConfig()
    fusion_region_margin_m: float = Field(
        100.0, description="a journey re-fuses the box of its signs and track grown by this")
    calibration_flag_rel: float = Field(
        0.03, description="flag a self-calibration whose fx/fy (relative) or cx/cy (relative to "
                          "the image size) differ more than this from the camera's stored one; "
                          "stored calibrations this close count as one camera (the stored one "
                          "is the mean of the largest such group)")
    # Seven: one or two wrong calibrations among them are outvoted, and a camera that really
    # changed (another lens under the same id) is the stored one again from its 3rd-4th journey.
    calibration_consensus_newest: int = Field(
        7, ge=1, description="the camera's newest self-calibrations that vote on its stored one")
    # Two: a single accepted self-calibration is wrong 1-2 times in 50
    # (docs/decisions/camera-calibration-consensus.md), two independent ones agreeing rarely.
    calibration_epoch_confirm: int = Field(
        2, ge=2, description="a camera's newest self-calibrations that, agreeing with each other "
                             "and each disagreeing with its epoch's calibration, start a new "
                             "epoch (a lens change)")

    # Map reads (see docs/service.md, "Map at scale").
    map_read_concurrency: int = Field(
        2, ge=1, description="heavy map reads (sign pages, tiles) run at once; more wait without "
                             "holding a thread the rest of the API needs")
    map_page_max: int = Field(
        2000, ge=1, description="signs per GET /signs page at most, whatever `limit` asks; "
                                "clients follow `next`")
    tile_max_zoom: int = Field(22, ge=0, le=30, description="deepest zoom of the vector tiles")
    tile_points_min_zoom: int = Field(
        15, ge=0, description="from this zoom on a tile holds every sign; below it, clusters")
    tile_max_points: int = Field(
        1000, ge=1, description="a tile with more signs than this is clustered at any zoom")
    tile_cluster_grid: int = Field(
        16, ge=1, le=256, description="a clustered tile has at most this many cells per side")
    tile_cache_max_zoom: int = Field(
        11, ge=-1, description="tiles at this zoom and below are kept in the API process until "
                               "the map changes; -1 = none")
    tile_cache_size: int = Field(4096, ge=1, description="tiles the cache holds at most")
    tile_cache_ttl_s: float = Field(
        300.0, gt=0, description="a cached tile is recomputed after this even if the map seems "
                                 "unchanged (a lagging clock on a worker host)")

    @field_validator("storage_url")
    @classmethod
    def _s3_url(cls, value: str | None) -> str | None:
        if value and (urlsplit(value).scheme != "s3" or not urlsplit(value).netloc):
            raise ValueError(f"storage_url must look like s3://bucket/prefix, not {value!r}")
        return value or None

    @cached_property
    def effective_database_url(self) -> str:
        if self.database_url:
            return self.database_url
        return f"sqlite:///{(self.data_dir / 'signmap.db').resolve()}"

    def as_env(self) -> dict[str, str]:
        """``SIGNMAP_*`` variables that make a child process's ``Settings()`` equal this one
        (nested groups as JSON, unset values left out)."""
        env = {}
        for name in type(self).model_fields:
            value = getattr(self, name)
            if isinstance(value, BaseModel):
                env[f"SIGNMAP_{name.upper()}"] = value.model_dump_json()
            elif value is not None:
                env[f"SIGNMAP_{name.upper()}"] = str(value)
        return env
