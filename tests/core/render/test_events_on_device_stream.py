"""A CUDA event is recorded on the stream the work it marks went on — the device's own current stream,
``device.stream.record_event(ev)`` — never with ``wp.record_event(ev)``, which records on the *current*
device's stream (cuda:0 unless a ``ScopedDevice`` says otherwise): with the work on another GPU in the same
process, a wait on the event would not cover it, or CUDA would refuse an event of another device's context."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[3]


def test_no_event_is_recorded_on_the_current_devices_stream():
    found = []
    for part in ("core", "app"):
        for path in sorted((ROOT / part).rglob("*.py")):
            for n, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
                if re.search(r"\bwp\.record_event\(", line):
                    found.append(f"{path.relative_to(ROOT)}:{n}")
    assert not found, found
