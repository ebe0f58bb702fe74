# ltlnav service image: the API (uvicorn) and the Celery worker run from the same image.
# Build: docker compose build   (see docker-compose.yml and docs/deploy.md)
FROM python:3.11-slim-bookworm

ENV PYTHONDONTWRITEBYTECODE=1 \
    PYTHONUNBUFFERED=1 \
    PIP_NO_CACHE_DIR=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1

# A compiler for the packages without a wheel for this platform (pybullet builds from source).
RUN apt-get update \
    && apt-get install -y --no-install-recommends build-essential \
    && rm -rf /var/lib/apt/lists/*

WORKDIR /app

# torch first and pinned to the CPU build: unpinned it pulls GBs of CUDA packages.
ARG TORCH_INDEX_URL=https://download.pytorch.org/whl/cpu
RUN pip install --index-url "$TORCH_INDEX_URL" torch==2.13.0

# Dependencies in their own layer, cached while only the sources change.
COPY pyproject.toml README.md ./
RUN mkdir -p planner envs workers service \
    && touch planner/__init__.py envs/__init__.py workers/__init__.py service/__init__.py \
    && pip install -e . \
    && rm -rf planner envs workers service

# Editable install: migrations/ and service/static/ are read from the source tree.
COPY alembic.ini ./
COPY migrations ./migrations
COPY planner ./planner
COPY envs ./envs
COPY workers ./workers
COPY service ./service
COPY examples ./examples
RUN pip install --no-deps -e . \
    && useradd --create-home --uid 10001 ltlnav \
    && mkdir -p /data/artifacts \
    && chown -R ltlnav /data

USER ltlnav
ENV LTLNAV_DATA_DIR=/data \
    LTLNAV_ARTIFACT_DIR=/data/artifacts \
    LTLNAV_HOST=0.0.0.0 \
    LTLNAV_PORT=8000
VOLUME ["/data"]
EXPOSE 8000

CMD ["uvicorn", "service.api.app:app", "--host", "0.0.0.0", "--port", "8000"]
