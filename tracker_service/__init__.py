"""The multiradar tracker service: CLI, ingest of recorded and live feeds, and (in later
stages) local tracking, bias estimation, fusion and publication."""

__version__ = "0.1.0"
