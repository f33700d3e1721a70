# syntax=docker/dockerfile:1
# `simpletrack serve` in a container: see docs/DEPLOY.md.
#
#   docker build -t simpletrack .
#   docker run --rm -p 127.0.0.1:9464:9464 -v simpletrack-state:/var/lib/simpletrack \
#       -e SIMPLETRACK_ZENOH__MODE=client -e SIMPLETRACK_ZENOH__CONNECT='["tcp/router:7447"]' \
#       simpletrack
#
# Every setting is a SIMPLETRACK_* environment variable (docs/SERVICE.md). Stop with SIGTERM and
# allow more than shutdown_timeout_s (20 s by default) for the final snapshot: compose.yaml and
# the Kubernetes manifests give 40 s / 45 s.
#
# There is no Docker engine on the development machines: scripts/check_dockerfile.py runs this
# file's RUN steps on the host in a throwaway directory and starts the result. Keep every
# absolute path of a RUN step in an ARG so that it can.

ARG PYTHON_IMAGE=python:3.11-slim-bookworm
ARG VENV=/opt/simpletrack
ARG STATE_DIR=/var/lib/simpletrack
ARG APP_UID=10001

# ---------------------------------------------------------------------------- build
FROM ${PYTHON_IMAGE} AS build
ARG VENV
ENV PIP_NO_CACHE_DIR=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1 \
    PYTHONDONTWRITEBYTECODE=1
WORKDIR /build
RUN python -m venv "${VENV}"

# Dependencies first (the client library's and the service extra's), from pyproject.toml alone,
# so that editing the source reuses this layer.
COPY pyproject.toml ./
RUN python -c "import tomllib; p = tomllib.load(open('pyproject.toml', 'rb'))['project']; print(*p['dependencies'], *p['optional-dependencies']['service'], sep='\n')" > requirements.txt \
 && "${VENV}/bin/pip" install -r requirements.txt

# Then the package itself; its dependencies are all in the layer above.
COPY README.md LICENSE ./
COPY schemas ./schemas
COPY service ./service
COPY clients ./clients
# The kernels are compiled here, into numba's cache beside the installed source, so that the
# service starts in under a second rather than compiling for ~20 s (a host whose CPU differs
# from the builder's compiles once more at start).
RUN "${VENV}/bin/pip" install --no-deps . \
 && "${VENV}/bin/simpletrack" serve --help > /dev/null \
 && "${VENV}/bin/python" -c "from simpletrack.core import jit; jit.preload()"

# ---------------------------------------------------------------------------- runtime
FROM ${PYTHON_IMAGE} AS runtime
ARG VENV
ARG STATE_DIR
ARG APP_UID
LABEL org.opencontainers.image.title="simpletrack-service" \
      org.opencontainers.image.description="SimpleTrack 3D multi-object tracking over Eclipse Zenoh" \
      org.opencontainers.image.licenses="Apache-2.0"

RUN groupadd --system --gid "${APP_UID}" simpletrack \
 && useradd --system --uid "${APP_UID}" --gid simpletrack --no-create-home \
        --home-dir "${STATE_DIR}" --shell /usr/sbin/nologin simpletrack \
 && mkdir -p "${STATE_DIR}" \
 && chown "${APP_UID}:${APP_UID}" "${STATE_DIR}" \
 && chmod 0750 "${STATE_DIR}"

COPY --from=build ${VENV} ${VENV}

# In a container the HTTP endpoint must bind the pod/container address, and snapshots go to
# the volume. Zenoh stays a loopback-only peer until told otherwise (compose/k8s make it a
# client of the router).
ENV PATH="${VENV}/bin:${PATH}" \
    PYTHONUNBUFFERED=1 \
    PYTHONDONTWRITEBYTECODE=1 \
    NO_COLOR=1 \
    SIMPLETRACK_METRICS_HOST=0.0.0.0 \
    SIMPLETRACK_METRICS_PORT=9464 \
    SIMPLETRACK_STATE_DIR=${STATE_DIR} \
    SIMPLETRACK_LOG_FORMAT=json

VOLUME ["/var/lib/simpletrack"]
# 9464: /metrics, /healthz, /readyz. 7447: Zenoh, only when run as a listening peer.
EXPOSE 9464 7447
USER ${APP_UID}:${APP_UID}

STOPSIGNAL SIGTERM
# The image's own Python (slim images have no curl); an exception exits 1: unhealthy.
HEALTHCHECK --interval=10s --timeout=3s --start-period=30s --retries=3 \
    CMD ["python", "-c", "import os, urllib.request as r; r.urlopen('http://127.0.0.1:%s/healthz' % os.environ.get('SIMPLETRACK_METRICS_PORT', '9464'), timeout=2)"]

ENTRYPOINT ["simpletrack"]
CMD ["serve"]
