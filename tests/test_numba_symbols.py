"""numba's compiled functions named uniquely per process (tracker_service/numba_symbols.py):
kernels compiled into the cache by different processes load together and give their own
results.

The collision is made to happen without the module: process A compiles an ``argsort`` and
process B a ``sort``; numba's quicksort for each is ``run_quicksort`` of an int64 array,
numbered from each process's counter. A's counter is first moved on by the difference of
the quicksorts' places in the two compilations (measured in a dry run), so that with
numba's counter (from 1 in every process) both would carry one name: loaded together, the
second kernel would call the first one's quicksort. With the module's random start they
do not meet.
"""

from __future__ import annotations

import ast
import os
import re
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np

import tracker_service

KERNELS = textwrap.dedent(
    """
    from tracker_service.numba_symbols import numba


    @numba.njit(cache=True)
    def order_of(values):
        return values.argsort()


    @numba.njit(cache=True)
    def sorted_of(values):
        out = values.copy()
        out.sort()
        return out
    """
)

VALUES = [5, 3, 9, 1, 7, 2, 8]


def run(directory: Path, script: str) -> str:
    """``script`` in a fresh interpreter, importing ``kernels`` from ``directory`` (its
    numba cache in ``directory/__pycache__``); its standard output."""
    done = subprocess.run(
        [sys.executable, "-c", textwrap.dedent(script)],
        cwd=directory,
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    return done.stdout


def compile_one(directory: Path, kernel: str, skip: int = 0) -> None:
    """``kernel`` compiled into the cache, numba's counter first moved on ``skip`` times."""
    run(
        directory,
        f"""
        import numpy as np
        from numba.core.bytecode import FunctionIdentity
        import kernels
        for _ in range({skip}):
            next(FunctionIdentity._unique_ids)
        kernels.{kernel}(np.array({VALUES}, dtype=np.int64))
        """,
    )


def numbers(directory: Path, kernel: str) -> tuple[int, int]:
    """The numbers of ``kernel`` and of its quicksort in its cached code."""
    (cached,) = (directory / "__pycache__").glob(f"kernels.{kernel}-*.nbc")
    code = cached.read_bytes()
    top = re.search(rb"7kernels\d+" + kernel.encode() + rb"B\d+v(\d+)", code)
    sort = re.search(rb"run_quicksortB\d+v(\d+)", code)
    assert top is not None and sort is not None
    return int(top.group(1)), int(sort.group(1))


def test_kernels_cached_by_two_processes_load_together(tmp_path: Path) -> None:
    dry, shared = tmp_path / "dry", tmp_path / "shared"
    for directory in (dry, shared):
        directory.mkdir()
        (directory / "kernels.py").write_text(KERNELS, encoding="utf-8")
    places = {}
    for kernel in ("order_of", "sorted_of"):
        compile_one(dry, kernel)
        top, sort = numbers(dry, kernel)
        places[kernel] = sort - top
    assert min(places.values()) >= 0
    lag = max(places.values())
    for kernel in ("order_of", "sorted_of"):
        compile_one(shared, kernel, skip=lag - places[kernel])
    # With numba's own counter these two would be equal (the collision).
    assert numbers(shared, "order_of")[1] != numbers(shared, "sorted_of")[1]
    values = np.array(VALUES, dtype=np.int64)
    for first, second in (("order_of", "sorted_of"), ("sorted_of", "order_of")):
        out = run(
            shared,
            f"""
            import numpy as np
            import kernels
            values = np.array({VALUES}, dtype=np.int64)
            print(kernels.{first}(values).tolist())
            print(kernels.{second}(values).tolist())
            """,
        ).split("\n")
        results = dict(zip((first, second), out, strict=False))
        assert results["order_of"] == str(np.argsort(values).tolist())
        assert results["sorted_of"] == str(np.sort(values).tolist())


def test_every_module_compiling_takes_numba_from_numba_symbols() -> None:
    """A module that imported numba itself could compile before the counter is moved: it
    imports numba from ``numba_symbols`` (its ``from numba.x import y`` beside that)."""
    root = Path(tracker_service.__file__).parent
    offenders = []
    for path in sorted(root.rglob("*.py")):
        if path.name == "numba_symbols.py":
            continue
        tree = ast.parse(path.read_text(encoding="utf-8"))
        imports = [n for n in ast.walk(tree) if isinstance(n, ast.Import | ast.ImportFrom)]
        from_ours = any(
            isinstance(n, ast.ImportFrom) and n.module == "tracker_service.numba_symbols"
            for n in imports
        )
        for node in imports:
            modules = (
                [alias.name for alias in node.names]
                if isinstance(node, ast.Import)
                else [node.module or ""]
            )
            if any(m == "numba" or m.startswith("numba.") for m in modules) and (
                isinstance(node, ast.Import) or not from_ours
            ):
                offenders.append(f"{path.relative_to(root)}:{node.lineno}")
    assert not offenders, offenders


def test_a_forked_child_numbers_apart_from_its_parent() -> None:
    """A forked child draws its own start (``os.register_at_fork``): it would otherwise go
    on from its parent's count, and the two would name their next functions alike."""
    from numba.core.bytecode import FunctionIdentity

    import tracker_service.numba_symbols  # noqa: F401  (the counter moved in this process)

    read_fd, write_fd = os.pipe()
    pid = os.fork()
    if pid == 0:  # the child: its next number to the parent, and out at once
        os.write(write_fd, str(next(FunctionIdentity._unique_ids)).encode())
        os._exit(0)
    os.close(write_fd)
    child = int(os.read(read_fd, 64))
    os.close(read_fd)
    os.waitpid(pid, 0)
    assert child != next(FunctionIdentity._unique_ids)
