# frictionwatch: the monitor in its own image. Build: docker build -t frictionwatch .
FROM python:3.11-slim
WORKDIR /app
COPY pyproject.toml README.md ./
COPY core core
COPY drivers drivers
COPY service service
COPY replay_logs replay_logs
RUN pip install --no-cache-dir . && useradd -r fw && mkdir -p /data && chown fw /data
USER fw
ENV NUMBA_CACHE_DIR=/tmp/numba
# warm the numba cache once at build time would bake CPU-specific code; it compiles at first start instead
ENTRYPOINT ["frictionwatch"]
CMD ["analyze", "replay_logs/demo.mcap"]
