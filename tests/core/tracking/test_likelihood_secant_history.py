"""The steps' secant length (engine_likelihood.SECANT_STEPS) keeps no state from one frame or run
to the next: the same track twice in one process (the stage engines cached and reused, each ending
with the θ it measured) gives the same results to the bit, on the ideal 128² talus-calcaneus views
(CPU device), jointly with the likelihood stage. With θ carried from run to run (each refinement
from the engine's last) it fails."""

from __future__ import annotations

from tests.core.tracking.test_joint_pipeline import _same, _track


def test_the_same_track_twice_gives_the_same_results(talus_calcaneus_128, monkeypatch):
    import core.tracking.engine_likelihood as el

    monkeypatch.setattr(el, "SECANT_STEPS", True)
    first = _track(talus_calcaneus_128, monkeypatch, True)
    again = _track(talus_calcaneus_128, monkeypatch, True)
    assert any((r.timing or {}).get("likelihood_taken") for r in first.results.values())
    _same(first, again)
