# The tracker service as a container: `docker run IMAGE decode /data/capture.pcap --summary`.
FROM python:3.11-slim
WORKDIR /app
COPY pyproject.toml README.md ./
COPY asterix ./asterix
COPY tracker_service ./tracker_service
COPY config ./config
COPY recordings ./recordings
RUN pip install --no-cache-dir .
ENTRYPOINT ["tracker-service"]
CMD ["decode", "recordings/three_sites.mcap", "--summary"]
