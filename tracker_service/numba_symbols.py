"""numba for the compiled kernels, with the symbol names of what it compiles unique to
this process: every module of ours that compiles imports numba from here
(``from tracker_service.numba_symbols import numba``), before anything is compiled.

numba names each function it compiles, and each function compiled into it (its sort, its
argsort, the implementations of numpy's functions), by its qualified name, its argument
types and a number from a counter that starts at 1 in every process
(``numba.core.bytecode.FunctionIdentity``); the on-disk cache (``cache=True``) keeps the
compiled code with those names. Two kernels compiled in two processes can then hold one
name for two different pieces of code: numba's quicksort made for ``argsort`` in one and
for ``sort`` in the other are both ``make_quicksort_impl.<locals>.run_quicksort`` of an
int64 array, and they get the same number whenever the two processes compiled as many
functions before them. A process that loads both kernels from the cache links both calls
to the one loaded first: the other kernel sorts where it should argsort, or the reverse.
Found as a segfault of the one-process daemon in its first second of fusion
(``fusion.kernels.identities_in_use``'s argsort resolved to
``tracking.association.kernels.gnn_assignment``'s sort), its cache written by the fusion
and radar processes of a roles run started on a cold cache; it gives wrong numbers
without a crash as readily (tests/test_numba_symbols.py). numba's issue 10128 is the same
collision between a gufunc and its wrapper.

Here the counter of each process starts at a random point of [1, 2^62), drawn again in
a forked child (which would otherwise go on from its parent's count): numbers drawn in
two processes (some 10^4 names each) meet with a chance of the order of 10^-14. The
cache stays valid: its index is keyed by the function's signature, the target and the
code's hash, never by these numbers.
"""

from __future__ import annotations

import itertools
import os
import secrets

import numba
from numba.core.bytecode import FunctionIdentity

__all__ = ["numba"]

COUNTER_RANGE = 1 << 62


def start_counter_at_random() -> None:
    """numba's counter of compiled functions from a random point (see the module)."""
    FunctionIdentity._unique_ids = itertools.count(1 + secrets.randbelow(COUNTER_RANGE - 1))


start_counter_at_random()
os.register_at_fork(after_in_child=start_counter_at_random)
