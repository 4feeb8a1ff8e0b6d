"""Helpers shared by the GUI tests of tests/app (import: ``from tests.app._helpers import job_ends``)."""

from __future__ import annotations

from contextlib import contextmanager

import pytest

# The tests wait for the job's own end signal (finished, failed or cancelled), however long a
# loaded machine takes to get there (Warp compiles its kernels in the first render). This is only
# the ceiling for a job that never ends, not a time the work is expected to take.
HUNG_JOB_MS = 30 * 60_000


@contextmanager
def job_ends(qtbot, pool, key: str, expect: str = "finished"):
    """Run the block, then wait until the pool's newest job ``key`` ends; fail unless it ended as
    ``expect`` (``"finished"``, ``"failed"`` or ``"cancelled"``).

    Yields the list of ends seen so far (``(kind, payload)``), so a test can also wait for an
    earlier event inside the block without missing a failure. A failure or a cancellation ends the
    wait at once, and the test fails with the worker's message unless that end was expected.
    """
    ends: list[tuple[str, object]] = []

    def on_finished(k, result):
        if k == key:
            ends.append(("finished", result))

    def on_failed(k, message):
        if k == key:
            ends.append(("failed", message))

    def on_cancelled(k):
        if k == key:
            ends.append(("cancelled", None))

    slots = ((pool.finished, on_finished), (pool.failed, on_failed), (pool.cancelled, on_cancelled))
    for signal, slot in slots:
        signal.connect(slot)
    try:
        yield ends
        qtbot.waitUntil(lambda: bool(ends), timeout=HUNG_JOB_MS)
    finally:
        for signal, slot in slots:
            signal.disconnect(slot)
    kind, payload = ends[0]
    if kind != expect:
        pytest.fail(f"background job {key!r} {kind} instead of being {expect}: {payload}")
