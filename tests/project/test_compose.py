"""docker-compose.yml and the Dockerfile, checked statically (no Docker here): the services,
their environment, the object store that replaced the shared data volume (issue 15) and
healthchecks, against the code they point at."""

from __future__ import annotations

import re
import shlex
from urllib.parse import urlparse

import pytest

from tests.utils.paths import REPO

yaml = pytest.importorskip("yaml")


@pytest.fixture(scope="module")
def compose() -> dict:
    return yaml.safe_load((REPO / "docker-compose.yml").read_text())


def _env(service: dict) -> dict[str, str]:
    return {k: str(v) for k, v in service["environment"].items()}


# The one-shot service that creates the bucket and exits (no healthcheck: it does not stay up).
ONE_SHOT = "minio-init"
# Variables read by boto3 rather than by Settings: the object store's endpoint and credentials.
AWS_VARIABLES = {"AWS_ENDPOINT_URL", "AWS_ACCESS_KEY_ID", "AWS_SECRET_ACCESS_KEY"}


def test_services_and_healthchecks(compose):
    services = compose["services"]
    assert set(services) == {"api", "worker", "postgres", "redis", "minio", ONE_SHOT}
    for name, service in services.items():
        if name == ONE_SHOT:
            assert "healthcheck" not in service and service["restart"] == "no"
            continue
        check = service["healthcheck"]
        assert check["test"][0] in ("CMD", "CMD-SHELL") and len(check["test"]) > 1, name
        assert check["retries"] >= 3, name
    api_deps, worker_deps = services["api"]["depends_on"], services["worker"]["depends_on"]
    assert {k: v["condition"] for k, v in api_deps.items()} == {
        "postgres": "service_healthy", "redis": "service_healthy",
        ONE_SHOT: "service_completed_successfully"}  # the bucket exists before any upload
    assert services[ONE_SHOT]["depends_on"]["minio"]["condition"] == "service_healthy"
    assert worker_deps["api"]["condition"] == "service_healthy"  # migrations ran
    assert services["worker"]["command"] == ["signmap", "worker"]
    assert "signmap db upgrade" in " ".join(services["api"]["command"])


def test_environment_points_at_the_compose_services(compose):
    services = compose["services"]
    api, worker = _env(services["api"]), _env(services["worker"])
    assert api == worker
    db = urlparse(api["SIGNMAP_DATABASE_URL"])
    pg = {k: str(v) for k, v in services["postgres"]["environment"].items()}
    assert db.scheme == "postgresql+psycopg" and db.hostname == "postgres"
    assert (db.username, db.path.lstrip("/")) == (pg["POSTGRES_USER"], pg["POSTGRES_DB"])
    assert db.password == pg["POSTGRES_PASSWORD"] == "${POSTGRES_PASSWORD:-signmap}"
    broker = urlparse(api["SIGNMAP_BROKER_URL"])
    assert (broker.scheme, broker.hostname) == ("redis", "redis")
    assert api["SIGNMAP_ADMIN_KEY"].startswith("${SIGNMAP_ADMIN_KEY:?")  # no default admin key
    from app.settings import Settings

    fields = set(Settings.model_fields)
    for name in set(api) - AWS_VARIABLES:
        assert name.startswith("SIGNMAP_") and name[8:].lower() in fields, name


def test_bundles_go_to_the_object_store_that_compose_starts(compose):
    services = compose["services"]
    env = _env(services["api"])
    assert AWS_VARIABLES <= set(env)
    store = urlparse(env["SIGNMAP_STORAGE_URL"])
    assert store.scheme == "s3" and store.path.strip("/")
    endpoint = urlparse(env["AWS_ENDPOINT_URL"])
    assert endpoint.hostname == "minio"
    assert f":{endpoint.port}" == services["minio"]["command"][-1]  # --address :9000
    minio = {k: str(v) for k, v in services["minio"]["environment"].items()}
    assert (env["AWS_ACCESS_KEY_ID"], env["AWS_SECRET_ACCESS_KEY"]) == (
        minio["MINIO_ROOT_USER"], minio["MINIO_ROOT_PASSWORD"])
    assert {k: str(v) for k, v in services[ONE_SHOT]["environment"].items()} == minio
    # The one-shot service creates exactly the bucket of SIGNMAP_STORAGE_URL, on the same server.
    script = shlex.split(services[ONE_SHOT]["entrypoint"][-1])
    assert f"http://minio:{endpoint.port}" in script
    assert script[-3:] == ["mb", "--ignore-existing", f"store/{store.hostname}"]
    assert services["minio"]["volumes"] == ["objects:/data"]


def test_workers_share_no_volume_with_the_api(compose):
    services = compose["services"]
    assert "volumes" not in services["worker"]  # its /data is its own (the image's VOLUME)
    data_dir = _env(services["api"])["SIGNMAP_DATA_DIR"]
    assert services["api"]["volumes"] == [f"api-data:{data_dir}"]
    assert set(compose["volumes"]) == {"pgdata", "redisdata", "objects", "api-data"}


def test_healthchecks_probe_what_the_code_provides(compose):
    from app.commands.service import create_service_app
    from app.settings import Settings
    from worker.tasks import ALIVE_FILE

    api_check = " ".join(compose["services"]["api"]["healthcheck"]["test"])
    path = re.search(r"http://127\.0\.0\.1:8000(/[\w/]+)", api_check).group(1)
    assert path in create_service_app(Settings(embedded_worker=False)).openapi()["paths"]
    assert "--port 8000" in " ".join(compose["services"]["api"]["command"])
    worker_check = " ".join(compose["services"]["worker"]["healthcheck"]["test"])
    assert f"'/tmp/{ALIVE_FILE.name}'" in worker_check  # the image's temp dir is /tmp


def test_dockerfile_installs_the_project_with_its_migrations():
    dockerfile = (REPO / "Dockerfile").read_text()
    for needed in ("COPY app ./app", "COPY worker ./worker", "COPY migrations ./migrations",
                   "alembic.ini", "pip install -e .", "USER signmap"):
        assert needed in dockerfile, needed
    ignored = (REPO / ".dockerignore").read_text().split()
    assert ".venv" in ignored and ".git" in ignored and "migrations" not in ignored
