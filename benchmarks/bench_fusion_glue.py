"""The fusion process's own CPU per radar batch outside the central stage: the decoding of
the batch's stage message (``stage_messages.decode_message``) and the pickling of its
calls to the output process (``command.OutputProcess``: ``advance`` and ``batch``, one
call where the code folds them), on the batches and outputs of a ``bench_central.py``
recording.

    python benchmarks/bench_central.py record artas150.mcap --seconds 40 -o central.pkl
    python benchmarks/bench_fusion_glue.py central.pkl [--batches 3000] [--repeats 5]

The recorded calls are replayed into a central stage for its outputs (untimed); each
batch is encoded alone in a message, as a radar process sends one datagram's. The pipe
is a stand-in that keeps the bytes: the write's system call is not timed, only what
this process does before it. The bytes are then unpickled as the output process does
(its CPU, for the balance). Medians of ``--repeats`` passes, CPU time
(``time.process_time``). Runs against whichever ``tracker_service`` is imported (a base
copy on ``PYTHONPATH``): a version whose ``OutputProcess.batch`` takes no reception time
sends an ``advance`` beside each ``batch``.
"""

from __future__ import annotations

import argparse
import copy
import importlib.util
import inspect
import pickle
import statistics
import time
from collections.abc import Callable
from typing import Any

import tracker_service
from tracker_service.central_stage import BatchOutput, CentralStage
from tracker_service.service import command
from tracker_service.stage_messages import (
    DatagramResult,
    RadarBatch,
    decode_message,
    encode_message,
)

Sample = tuple[list[RadarBatch], list[BatchOutput], list[str]]


def sample(path: str, batches: int) -> Sample:
    """The first ``batches`` radar batches of a recording of calls, as received, and the
    central stage's outputs of them."""
    with open(path, "rb") as stream:
        calls, _ = pickle.load(stream)  # a file of one's own recording
    stage: CentralStage | None = None
    taken: list[RadarBatch] = []
    outputs: list[BatchOutput] = []
    for name, args, kwargs in calls:
        if name == "__init__":
            stage = CentralStage(*args, **kwargs)
            continue
        assert stage is not None
        if name == "process":
            taken.append(copy.deepcopy(args[0]))
            outputs.append(stage.process(*args, **kwargs))
            if len(taken) >= batches:
                break
        else:
            getattr(stage, name)(*args, **kwargs)
    assert stage is not None
    return taken, outputs, list(stage.fusion_sources)


class _KeptBytes:
    """The pipe's writing end, keeping what is sent."""

    def __init__(self) -> None:
        self.sent: list[bytes] = []

    def send_bytes(self, data: bytes) -> None:
        self.sent.append(data)


def proxy(pipe: _KeptBytes) -> command.OutputProcess:
    """An ``OutputProcess`` without its process: its calls pickled into ``pipe``."""
    outputs = command.OutputProcess.__new__(command.OutputProcess)
    state: dict[str, Any] = {
        "_failed": None,
        "_next_check": float("inf"),
        "_calls": pipe,
        "_data_time": None,
        "restarts": 0,
        "last_restart": None,
    }
    if importlib.util.find_spec("tracker_service.service.call_pickle") is not None:
        from tracker_service.service.call_pickle import CallPickler

        state["_pickler"] = CallPickler()
    vars(outputs).update(state)
    return outputs


def passes(run: Callable[[], None], repeats: int) -> float:
    seconds = []
    for _ in range(repeats):
        started = time.process_time()
        run()
        seconds.append(time.process_time() - started)
    return statistics.median(seconds)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("calls", help="a bench_central.py recording")
    parser.add_argument("--batches", type=int, default=3000)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    batches, outputs, sources = sample(args.calls, args.batches)
    payloads = [
        encode_message(DatagramResult(order=b.order, received=b.received, batches=[b]))
        for b in batches
    ]
    folded = "received" in inspect.signature(command.OutputProcess.batch).parameters
    pipe = _KeptBytes()

    def decode() -> None:
        for payload in payloads:
            decode_message(payload)

    def calls() -> None:
        pipe.sent.clear()
        outputs_proxy = proxy(pipe)
        for batch, output in zip(batches, outputs, strict=True):
            if folded:
                outputs_proxy.batch(output, sources, batch.received)
            else:
                outputs_proxy.advance(batch.received)
                outputs_proxy.batch(output, sources)

    def unpickle() -> None:
        for data in pipe.sent:
            pickle.loads(data)

    n = len(batches)
    plots = sum(len(b.plots) for b in batches)
    figures = {
        "decode": passes(decode, args.repeats),
        "output calls": passes(calls, args.repeats),
        "output process's unpickling": passes(unpickle, args.repeats),
    }
    print(f"code: {tracker_service.__file__}; {n} batches, {plots} plots")
    print(", ".join(f"{name} {seconds / n * 1e6:.1f} us" for name, seconds in figures.items()))


if __name__ == "__main__":
    main()
