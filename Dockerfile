# orbit-emulator web app: REST API, control page and the viser 3D viewer (/viewer/) on 8000.
# Bound to 0.0.0.0, so every request needs the token: ORBIT_EMULATOR_TOKEN if given, else
# one generated at start and printed in the log (the link that carries it).
#
#   docker build -t orbit-emulator .
#   docker run --rm -p 8000:8000 -e ORBIT_EMULATOR_TOKEN=<16+ characters> --shm-size=1g \
#       --ulimit rtprio=20 orbit-emulator
#
# --shm-size=1g: the telemetry rings live in /dev/shm (up to 128 MiB a run, the last two
# runs kept); Docker's default 64 MiB holds no two-arm run, and a start that does not fit
# is refused (422 naming loop.telemetry_capacity).
# --ulimit rtprio=20 lets the emulator loop process (non-root) run SCHED_FIFO, which keeps
# its 2 ms deadlines on a loaded host; without it the loop runs with default scheduling.
FROM python:3.11-slim

ENV PYTHONDONTWRITEBYTECODE=1 \
    PYTHONUNBUFFERED=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1 \
    NUMBA_CACHE_DIR=/opt/numba-cache \
    NUMBA_CPU_NAME=generic

WORKDIR /app

# libgomp1: Pinocchio's wheel links OpenMP's runtime, which slim images do not ship
# (a base that has it already, such as scripts/container-test's, needs no package index)
RUN dpkg -s libgomp1 >/dev/null 2>&1 \
    || (apt-get update && apt-get install -y --no-install-recommends libgomp1 \
        && apt-get clean && rm -rf /var/lib/apt/lists/*)

# optional build arguments for pip, not kept in the image: a certificate bundle, a
# constraints file (scripts/container-test pins the host's versions with it)
ARG PIP_CERT
ARG PIP_CONSTRAINT

COPY pyproject.toml README.md ./
COPY scripts/container-entry /usr/local/bin/container-entry
COPY app ./app
COPY static ./static
# pycollada: trimesh needs it to load the UR10 .dae meshes of the 3D view
# (a cache mount: a rebuild on the same machine downloads nothing again, and the image
# keeps no pip cache)
RUN --mount=type=cache,target=/root/.cache/pip pip install . pycollada \
    && useradd --create-home --uid 1000 emulator \
    && mkdir -p /opt/numba-cache && chmod 1777 /opt/numba-cache \
    && mkdir -p /app/runs && chmod 1777 /app/runs
# (/app/runs: where `serve` keeps its web runs, runs/web, whatever the user it runs as;
# mount a volume there to keep them)

# the manual, built now (strict: a broken link fails the build) into /app/site, which
# `serve` offers at /manual/ with its search; its sources are not kept. Nothing in it is
# fetched when it is read (no web fonts, a local KaTeX and search index). Its tools (the
# docs extra of pyproject.toml) are not held to PIP_CONSTRAINT: they change no number the
# emulator computes, and a base's older Python may not take the host's versions
# (pymdown-extensions 13 needs Python 3.11.5, Debian bookworm has 3.11.2).
RUN --mount=type=cache,target=/root/.cache/pip python -c "import tomllib; \
        print('\n'.join(tomllib.load(open('pyproject.toml', 'rb')) \
                        ['project']['optional-dependencies']['docs']))" >/tmp/docs.txt \
    && env -u PIP_CONSTRAINT pip install -r /tmp/docs.txt && rm /tmp/docs.txt
COPY mkdocs.yml ./
COPY docs ./docs
COPY docs_src ./docs_src
# (the build imports app: numba's cache of it goes to a folder of its own, not the image's
# cache, which the warm-up below fills as the user that runs the image)
RUN NO_MKDOCS_2_WARNING=1 NUMBA_CACHE_DIR=/tmp/docs-numba-cache \
        mkdocs build --strict --quiet --site-dir /app/site \
    && test -f /app/site/index.html && test -f /app/site/search/search_index.json \
    && rm -rf docs docs_src mkdocs.yml /tmp/docs-numba-cache

USER emulator
# static/ and the manual are found in the working directory (the installed package lives
# elsewhere)
ENV ORBIT_EMULATOR_STATIC=/app/static \
    ORBIT_EMULATOR_MANUAL=/app/site
# compile the numba kernels now, into the image, for a generic x86-64 CPU (numba's cache
# is keyed to the CPU it compiled for): every shipped scenario stepped ideal and hil
# (app/runs/warm.py), so that a first run or `serve` on any host loads them instead of
# compiling for 20 s or more; run from / so that it warms the installed package (the one
# `orbit-emulator` imports), not /app/app; the cache folder and the ones numba made in it
# are open to any uid (--user: numba loads a cache only from a folder it could write to)
RUN cd / && python -m app.runs.warm \
    && find /opt/numba-cache -mindepth 1 -exec chmod a+rwX {} +

EXPOSE 8000

HEALTHCHECK --interval=15s --timeout=5s --start-period=60s --retries=3 \
    CMD ["python", "-c", "import json, sys, urllib.request; t = open('/tmp/orbit-emulator-token').read().strip(); r = urllib.request.urlopen(urllib.request.Request('http://127.0.0.1:8000/api/health', headers={'Authorization': 'Bearer ' + t}), timeout=4); sys.exit(0 if json.load(r)['status'] in ('ok', 'degraded') else 1)"]

# the entry point only makes the build's numba cache usable on a read-only file system
ENTRYPOINT ["container-entry"]
CMD ["orbit-emulator", "serve", "--host", "0.0.0.0", "--generate-token", "--token-file", "/tmp/orbit-emulator-token"]
