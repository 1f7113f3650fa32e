# orbit-emulator web app: REST API + control page on 8000, viser 3D viewer on 8080.
#
#   docker build -t orbit-emulator .
#   docker run --rm -p 127.0.0.1:8000:8000 -p 127.0.0.1:8080:8080 --ulimit rtprio=20 orbit-emulator
#
# --ulimit rtprio=20 lets the emulator loop process (non-root) run SCHED_FIFO, which keeps
# its 2 ms deadlines on a loaded host; without it the loop runs with default scheduling.
FROM python:3.11-slim

ENV PYTHONDONTWRITEBYTECODE=1 \
    PYTHONUNBUFFERED=1 \
    PIP_NO_CACHE_DIR=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1 \
    NUMBA_CACHE_DIR=/tmp/numba-cache

WORKDIR /app

# dependencies first (better layer caching), then the project itself
COPY pyproject.toml README.md ./
COPY app ./app
COPY static ./static
# pycollada: trimesh needs it to load the UR10 .dae meshes of the 3D view
RUN pip install . pycollada \
    && useradd --create-home --uid 1000 emulator

USER emulator
# static/ is found in the working directory (the installed package lives elsewhere)
ENV ORBIT_EMULATOR_STATIC=/app/static

EXPOSE 8000 8080

HEALTHCHECK --interval=15s --timeout=5s --start-period=60s --retries=3 \
    CMD ["python", "-c", "import json, sys, urllib.request; r = urllib.request.urlopen('http://127.0.0.1:8000/api/health', timeout=4); sys.exit(0 if json.load(r)['status'] == 'ok' else 1)"]

CMD ["orbit-emulator", "serve", "--host", "0.0.0.0"]
