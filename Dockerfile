# Signmap API and worker image (one image, two commands; see docker-compose.yml).
FROM python:3.11-slim

ENV PYTHONDONTWRITEBYTECODE=1 PYTHONUNBUFFERED=1 PIP_NO_CACHE_DIR=1 \
    SIGNMAP_DATA_DIR=/data
# pycolmap's and OpenCV's wheels use OpenMP.
RUN apt-get update && apt-get install -y --no-install-recommends libgomp1 \
    && rm -rf /var/lib/apt/lists/*

WORKDIR /app
COPY pyproject.toml alembic.ini ./
COPY app ./app
COPY worker ./worker
COPY migrations ./migrations
# Editable, so that `signmap db upgrade` finds /app/migrations next to the package.
RUN pip install -e .

RUN useradd --create-home --uid 1000 signmap && mkdir -p /data && chown signmap /data
USER signmap
VOLUME ["/data"]
EXPOSE 8000
CMD ["signmap", "serve", "--host", "0.0.0.0", "--port", "8000"]
