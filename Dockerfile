# frictionwatch serve in its own image: the bundled demo log replayed in a loop, the API and dashboard on port 8080.
#   docker build -t frictionwatch .
#   docker run -p 127.0.0.1:8080:8080 -v fw-data:/data \
#       --mount type=bind,src="$PWD/token",dst=/run/secrets/frictionwatch_token,readonly frictionwatch
# The service binds 0.0.0.0 inside the container, so it needs the token (the state-changing requests' bearer
# token): a file mounted at /run/secrets/frictionwatch_token (a bind mount as above, or a compose/swarm secret of that
# name). Without it the service refuses to start, in one line. The store (SQLite, WAL) lives in the /data volume.
FROM python:3.11-slim

# PIP_CONSTRAINT: every dependency, and setuptools for the build, at its version in constraints.txt (the pinned set)
ENV PYTHONUNBUFFERED=1 \
    PIP_NO_CACHE_DIR=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1 \
    PIP_CONSTRAINT=/app/constraints.txt

RUN useradd --system --uid 10001 --create-home --home-dir /home/fw fw \
    && mkdir -p /data /opt/numba-cache \
    && chown fw:fw /data /opt/numba-cache

WORKDIR /app
COPY constraints.txt pyproject.toml README.md ./
COPY core core
COPY drivers drivers
COPY service service
RUN pip install '.[postgres]' && rm -rf build *.egg-info
COPY replay_logs/demo.mcap replay_logs/demo.mcap

# The numba cache, compiled here once instead of at every container start (52-144 s before the first result).
# NUMBA_CPU_NAME=generic: numba keys its cache on the CPU name and features (numba.core.codegen.magic_tuple); with the
# generic CPU and no features the key is the same on every x86-64 host, so the code compiled on the build machine is
# used wherever the image runs (at the cost of the host's wider vector instructions). The warm-up runs as the user
# the service runs as, so a kernel it did not reach can still be compiled and cached at run time; serve's own warm-up
# (service/warmup.py, design note 126) last, so the container's start loads what it compiles instead.
USER fw
ENV NUMBA_CACHE_DIR=/opt/numba-cache \
    NUMBA_CPU_NAME=generic
RUN frictionwatch analyze replay_logs/demo.mcap >/dev/null \
    && frictionwatch simulate --engine genset-v20 --rpm 1500 --load 0.75 --cycles 6 --seed 1 -o /tmp/warm/v20.mcap \
    && frictionwatch analyze /tmp/warm/v20.mcap >/dev/null \
    && rm -rf /tmp/warm \
    && python -m frictionwatch.service.warmup replay_logs/demo.mcap

VOLUME /data
EXPOSE 8080
# healthy while the API answers /health, "ok" or "degraded": a degraded engine (lagging, stale, not yet analysing)
# is still alive and serving, /health says what is wrong, and a restart would cure none of it (it drops the queue and
# lags again: an orchestrator restarting on "unhealthy" would make a slow plant a restart loop). Unhealthy: no
# answer, or an engine whose threads all ended while its sources run (a restart can cure those).
# service/healthcheck.py; its one line shows in `docker inspect`.
HEALTHCHECK --interval=30s --timeout=5s --start-period=60s --retries=3 \
    CMD ["python", "-m", "frictionwatch.service.healthcheck", "http://127.0.0.1:8080/api/v1/health"]
ENTRYPOINT ["frictionwatch"]
CMD ["serve", "--source", "mcap:replay_logs/demo.mcap?loop=1&speed=1", "--host", "0.0.0.0", "--port", "8080", \
     "--data-dir", "/data", "--token-file", "/run/secrets/frictionwatch_token"]
