# The tracker service as a container: the daemon on a mounted configuration.
#   docker build -t tracker-service .
#   docker run --rm --network host -v "$PWD/config:/config:ro" tracker-service
# Other commands run the same image: `docker run --rm IMAGE decode /data/capture.pcap`.
FROM python:3.11-slim
WORKDIR /app
COPY pyproject.toml README.md ./
COPY asterix ./asterix
COPY tracker_service ./tracker_service
COPY config ./config
COPY recordings ./recordings
RUN pip install --no-cache-dir . \
    && useradd --system --uid 10001 --home-dir /var/lib/tracker tracker \
    && mkdir -p /var/lib/tracker/logs \
    && chown -R tracker /var/lib/tracker
USER tracker
WORKDIR /var/lib/tracker
# Zenoh (the daemon listens where the configuration or --zenoh-listen says; 7447 by custom).
EXPOSE 7447
# The daemon touches the file at every status message (every 5 s of data, every few
# seconds when the feeds are quiet).
HEALTHCHECK --interval=30s --timeout=5s --start-period=20s --retries=3 \
    CMD ["tracker-service", "health", "--file", "/tmp/tracker-health", "--max-age", "30"]
ENTRYPOINT ["tracker-service"]
CMD ["run", "--config", "/config/tracker.toml", "--zenoh-listen", "tcp/0.0.0.0:7447", \
     "--health-file", "/tmp/tracker-health"]
