"""``tracker-service init DIR``: the example configuration and the scenarios, written into
DIR so that a user of an installed wheel can follow the README.

The files are those of the repository's ``config/``: the wheel installs them under
``share/tracker-service/config`` of its environment (``pyproject.toml``, data files); a
source checkout (an editable install) reads them where they are. DIR gets
``tracker.toml`` (the example, ``config/example.toml``, which listens to the
``three_sites`` scenario's radars), ``scenarios/*.toml`` and ``zenoh/`` (the Zenoh TLS
and access-control examples and ``make-certs.sh``). Existing files are kept unless
``--force``.
"""

from __future__ import annotations

import argparse
import shutil
import site
import sys
import sysconfig
from pathlib import Path

__all__ = ["add_arguments", "example_directory", "run", "write_examples"]

_SHARE = Path("share", "tracker-service", "config")


def example_directory() -> Path:
    """Where the example configuration is: the environment's share/ (a wheel), the user
    base's (``pip install --user``), or the source checkout's config/."""
    candidates = [
        Path(sysconfig.get_path("data")) / _SHARE,
        Path(site.USER_BASE or "") / _SHARE,
        Path(__file__).resolve().parents[1] / "config",
    ]
    for candidate in candidates:
        if (candidate / "example.toml").is_file():
            return candidate
    raise FileNotFoundError(
        "the example configuration is not installed (looked in "
        + ", ".join(str(c) for c in candidates)
        + "): reinstall tracker-service"
    )


def _files(source: Path) -> list[tuple[Path, Path]]:
    """(source file, its name in DIR)."""
    pairs = [(source / "example.toml", Path("tracker.toml"))]
    pairs += [(p, Path("scenarios", p.name)) for p in sorted(source.glob("scenarios/*.toml"))]
    pairs += [
        (p, Path("zenoh", p.name))
        for p in sorted((source / "zenoh").glob("*"))
        if p.is_file() and (p.suffix == ".json5" or p.name == "make-certs.sh")
    ]
    return pairs


def write_examples(directory: Path, force: bool = False) -> tuple[list[Path], list[Path]]:
    """(written, kept because they exist) files of ``directory``."""
    written, kept = [], []
    for source, name in _files(example_directory()):
        target = directory / name
        if target.exists() and not force:
            kept.append(target)
            continue
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(source, target)
        if source.name.endswith(".sh"):
            target.chmod(0o755)
        written.append(target)
    return written, kept


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("directory", help="where to write them (created if need be)")
    parser.add_argument("--force", action="store_true", help="overwrite files that exist")


def run(args: argparse.Namespace) -> int:
    directory = Path(args.directory)
    try:
        written, kept = write_examples(directory, args.force)
    except OSError as exc:
        print(f"tracker-service init: {exc}", file=sys.stderr)
        return 2
    for path in written:
        print(f"wrote {path}")
    for path in kept:
        print(f"kept {path} (exists; --force overwrites it)")
    config = directory / "tracker.toml"
    print(
        f"next: tracker-service run --config {config}; in another shell: tracker-service "
        f"simulate {directory / 'scenarios' / 'three_sites.toml'} -o three_sites.mcap, then "
        f"tracker-service play three_sites.mcap --config {config} --now",
        file=sys.stderr,
    )
    return 0
