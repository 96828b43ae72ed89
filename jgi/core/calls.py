"""Jitted calls kept in flight concurrently, their results consumed in call order.

XLA's CPU backend splits each large kernel over the cores and joins them at its end, so a
program that runs one call at a time leaves cores idle at every join and during its small
kernels. Independent calls (chunks of paths or photons) are therefore run ``CALL_STREAMS`` at a
time, each from its own thread, all sharing one compiled function; their kernels fill each
other's gaps. Results are consumed in call order, whichever call finishes first, so nothing
depends on timing or on the number of calls in flight.
"""

from __future__ import annotations

import os
from collections import deque
from concurrent.futures import ThreadPoolExecutor
from typing import Callable, Iterator

import numpy as np

# calls in flight: each fills the others' idle cores (perf: docs/performance.md#concurrent-calls);
# the environment variable JGI_CALL_STREAMS overrides it (1: one call at a time)
CALL_STREAMS = max(1, int(os.environ.get("JGI_CALL_STREAMS", "2")))


def ordered_calls(call: Callable[[int], object], n_calls: int, *,
                  streams: int | None = None) -> Iterator:
    """Yield ``call(i)`` for i < ``n_calls``, in that order, with up to ``streams`` (default
    ``CALL_STREAMS``) calls running at once, each from its own thread. ``call`` should return
    host (numpy) values, so that its thread waits for the device work it started."""
    streams = max(1, min(streams or CALL_STREAMS, n_calls))
    if streams == 1:
        for i in range(n_calls):
            yield call(i)
        return
    with ThreadPoolExecutor(streams) as pool:
        pending = deque(pool.submit(call, i) for i in range(streams))
        for i in range(n_calls):
            result = pending.popleft().result()
            if i + streams < n_calls:
                pending.append(pool.submit(call, i + streams))
            yield result


def sum_calls(call: Callable[[int], tuple], n_calls: int, *, streams: int | None = None,
              on_done: Callable[[int], None] | None = None) -> tuple[np.ndarray, int]:
    """Sum over i < ``n_calls`` of ``call(i) -> (image part, count of dropped paths)``, as a
    float32 numpy array and an int, run as :func:`ordered_calls`. The parts are added in call
    order, so the sum does not depend on timing or on ``streams``. ``on_done(i)`` runs in the
    caller's thread after part i is added (progress bars)."""
    def run(i):
        part, bad = call(i)
        return np.asarray(part, np.float32), int(bad)

    img, bad = None, 0
    for i, (part, nbad) in enumerate(ordered_calls(run, n_calls, streams=streams)):
        img = part if img is None else img + part
        bad += nbad
        if on_done is not None:
            on_done(i)
    return img, bad
