# syntax=docker/dockerfile:1
# posefix: the API server, the worker and the built front end in one image.
#   docker build -t posefix .          (docker-compose.yml does this for you)
# Stage 1 builds the browser editor; stage 2 installs the Python app into a virtualenv;
# stage 3 is the slim runtime with neither node nor compilers.

FROM node:22-bookworm-slim AS frontend
WORKDIR /app/frontend
COPY frontend/package.json frontend/package-lock.json ./
RUN npm ci --no-audit --no-fund --loglevel=error
COPY frontend/ ./
RUN npm run build

FROM python:3.11-slim-bookworm AS python
ENV PIP_NO_CACHE_DIR=1 PIP_DISABLE_PIP_VERSION_CHECK=1
WORKDIR /app
RUN python -m venv /opt/venv
COPY README.md ./
COPY backend/ backend/
# Editable, so the package stays at /app/backend beside /app/migrations, where
# `posefix db upgrade` looks for them.
RUN /opt/venv/bin/pip install -e ./backend

FROM python:3.11-slim-bookworm AS runtime
LABEL org.opencontainers.image.title="posefix" \
      org.opencontainers.image.description="Crowdsourced correction of vehicle trajectories" \
      org.opencontainers.image.licenses="Apache-2.0"
ENV PATH=/opt/venv/bin:$PATH \
    PYTHONUNBUFFERED=1 \
    POSEFIX_DATA_DIR=/var/lib/posefix \
    FORWARDED_ALLOW_IPS=*
RUN useradd --system --uid 10001 --home-dir /var/lib/posefix --create-home posefix
WORKDIR /app
COPY --from=python /opt/venv /opt/venv
COPY --from=python /app /app
COPY migrations/ migrations/
COPY data/ data/
COPY --from=frontend /app/frontend/dist frontend/dist
USER posefix
VOLUME ["/var/lib/posefix"]
EXPOSE 8000
HEALTHCHECK --interval=15s --timeout=3s --start-period=20s --retries=3 \
  CMD ["python", "-c", "import urllib.request; urllib.request.urlopen('http://127.0.0.1:8000/healthz', timeout=2)"]
CMD ["posefix", "serve", "--host", "0.0.0.0", "--port", "8000"]
