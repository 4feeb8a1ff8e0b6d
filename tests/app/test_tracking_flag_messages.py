"""After a tracking run the window names the first flagged frames one by one and counts the rest
(a long trial's trajectory check flags hundreds)."""

from __future__ import annotations

from types import SimpleNamespace

from app.tracking_actions import MAX_FLAG_MESSAGES, TrackingActions


def _show(n):
    said = []
    stub = SimpleNamespace(_reload=lambda: None, window=SimpleNamespace(notify=said.append))
    flagged = [{"bone": "talus", "frame": k, "flags": ["off the trajectory (test)"]} for k in range(n)]
    TrackingActions._show(stub, (object(), {"flagged": flagged, "summary": {"status": "complete",
                                                                             "results": 100}}))
    return said


def test_few_flags_are_each_named_many_are_counted():
    said = _show(3)
    assert len(said) == 4 and said[0].startswith("talus frame 0: off the trajectory")
    assert "3 flagged for review" in said[-1]
    said = _show(MAX_FLAG_MESSAGES + 25)
    assert len(said) == MAX_FLAG_MESSAGES + 2
    assert "25 more flagged frames" in said[-2] and f"{MAX_FLAG_MESSAGES + 25} flagged" in said[-1]
