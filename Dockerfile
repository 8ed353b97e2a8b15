# The tracker service as a container: the daemon on a mounted configuration, publishing
# over mutual TLS with access control (docs/security.md):
#   tracker-service init config-prod      # or copy config/: tracker.toml, zenoh/
#   config-prod/zenoh/make-certs.sh config-prod/zenoh/certs tracker.example.org 192.0.2.10
#   sudo chown 10001 config-prod/zenoh/certs/service.key   # the image's user reads its key
#   docker build -t tracker-service .
#   docker run --rm --network host -v "$PWD/config-prod:/config:ro" tracker-service
# Without a mount, /config holds the example configuration (`tracker-service init`) and no
# certificates: try it in plaintext on this host only with
#   docker run --rm --network host tracker-service run --config /config/tracker.toml \
#       --zenoh-listen tcp/127.0.0.1:7447 --health-file /tmp/tracker-health
# Other commands run the same image: `docker run --rm IMAGE decode /data/capture.pcap`.
# Pinned: the Python the suite runs on, on a fixed Debian release.
FROM python:3.11.7-slim-bookworm
WORKDIR /app
COPY pyproject.toml README.md LICENSE constraints.txt ./
COPY asterix ./asterix
COPY tracker_service ./tracker_service
COPY config ./config
COPY recordings ./recordings
# The dependencies at the versions of constraints.txt, nothing newer.
RUN pip install --no-cache-dir -c constraints.txt . \
    && useradd --system --uid 10001 --home-dir /var/lib/tracker tracker \
    && mkdir -p /var/lib/tracker/logs \
    && tracker-service init /config \
    && chown -R tracker /var/lib/tracker
USER tracker
WORKDIR /var/lib/tracker
# numba's cache, filled as the user the service runs as (the installed package's own
# directory is not writable to it: numba caches under ~/.cache/numba), so that a container
# starts in seconds rather than compiling for two minutes, on hosts of the build host's CPU
# model (numba keeps its cache per CPU model: docs/deployment.md, "Limits").
RUN tracker-service warm-up --config /config/tracker.toml
# Zenoh over TLS (the command below; the configuration may add endpoints, never plaintext
# beside TLS unless it says allow_plaintext).
EXPOSE 7447
# From the daemon's own status, which it writes into the file every 5 s of data (every
# few seconds when the feeds are quiet): unhealthy when the status is older than 30 s
# (the daemon stuck or gone), every radar has been silent for 60 s, or the chain is 30 s
# behind the wall clock (`tracker-service health --help`); one radar silent or another
# degradation is printed into the health log but stays healthy. Exit codes 0 and 1 only.
HEALTHCHECK --interval=30s --timeout=10s --start-period=180s --retries=3 \
    CMD ["tracker-service", "health", "--file", "/tmp/tracker-health", "--max-age", "30", \
         "--container", "--silent-for", "60", "--behind", "30"]
ENTRYPOINT ["tracker-service"]
# The certificates and the access control come from the mounted /config/zenoh/service.json5
# (relative paths from its directory: /config/zenoh/certs/); without them the daemon stops
# at start-up saying which file is missing.
CMD ["run", "--config", "/config/tracker.toml", \
     "--zenoh-config", "/config/zenoh/service.json5", "--zenoh-listen", "tls/0.0.0.0:7447", \
     "--health-file", "/tmp/tracker-health"]
