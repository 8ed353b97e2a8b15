# The tracker service as a container: the daemon on a mounted configuration, publishing
# over mutual TLS with access control (docs/security.md):
#   config/zenoh/make-certs.sh config/zenoh/certs tracker.example.org 192.0.2.10
#   sudo chown 10001 config/zenoh/certs/service.key   # the image's user reads its key
#   cp config/example.toml config/tracker.toml        # your radars
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
# Zenoh over TLS (the command below; the configuration may add endpoints, never plaintext
# beside TLS unless it says allow_plaintext).
EXPOSE 7447
# The daemon touches the file at every status message (every 5 s of data, every few
# seconds when the feeds are quiet).
HEALTHCHECK --interval=30s --timeout=5s --start-period=20s --retries=3 \
    CMD ["tracker-service", "health", "--file", "/tmp/tracker-health", "--max-age", "30"]
ENTRYPOINT ["tracker-service"]
# The certificates and the access control come from the mounted /config/zenoh/service.json5
# (relative paths from its directory: /config/zenoh/certs/); without them the daemon stops
# at start-up saying which file is missing.
CMD ["run", "--config", "/config/tracker.toml", \
     "--zenoh-config", "/config/zenoh/service.json5", "--zenoh-listen", "tls/0.0.0.0:7447", \
     "--health-file", "/tmp/tracker-health"]
