"""The likelihood stage's set-up, robust factors and sandwich recorded and replayed as graphs
(core.tracking.likelihood_segments.SEGMENT_GRAPHS, Warp's CPU graphs here) against their calls made one
by one: the same poses, covariances and steps to the bit, on the ideal 128² talus-calcaneus frame — each
bone alone (every piece: its first call run as it is, its second captured, the third replayed) and both
side by side with the other subtracted (its DRRs in the set-up's piece on the recorded step's path)."""

from __future__ import annotations

import numpy as np
import pytest

from tests.core.tracking.stage_helpers import stage_calls


def _runs(r, frame, calls, n: int = 3) -> list:
    from core.tracking.final_stage import final_stage, final_stages

    out = []
    for _ in range(n):
        out += [final_stage(r, frame, res, **{**kw, "others": None}) for res, kw in calls]
        out += final_stages(r, frame, calls)
    return out


@pytest.fixture
def graphs(monkeypatch):
    """The graphs launched (a list of the segments' names, one a launch)."""
    import warp as wp

    import core.tracking.likelihood_segments as seg

    launched: list = []
    plain = wp.capture_launch

    def counted(g, *a, **k):
        launched.append(g)
        return plain(g, *a, **k)

    monkeypatch.setattr(wp, "capture_launch", counted)
    monkeypatch.setattr(seg, "FAILED", None)
    return launched


@pytest.mark.parametrize("step_graph", [None, True])
def test_pieces_replayed_give_the_same_stages(talus_calcaneus_128, graphs, monkeypatch, step_graph):
    """(STEP_GRAPH True: the recorded step's path, a CUDA device's, where the neighbours' DRRs are in the
    set-up's piece too.)"""
    import core.tracking.engine_likelihood as el
    import core.tracking.likelihood_segments as seg

    monkeypatch.setattr(el, "STEP_GRAPH", step_graph)
    r, frame, calls, _ = stage_calls(talus_calcaneus_128)
    monkeypatch.setattr(seg, "SEGMENT_GRAPHS", False)
    plain = _runs(r, frame, calls)
    assert not graphs
    monkeypatch.setattr(seg, "SEGMENT_GRAPHS", True)
    replayed = _runs(r, frame, calls)
    assert seg.FAILED is None and len(graphs) >= 12  # (every piece of every run after its first two calls)
    for a, b in zip(plain, replayed, strict=True):
        assert a.timing["likelihood_taken"] == b.timing["likelihood_taken"] == 1
        assert a.timing["likelihood_steps"] == b.timing["likelihood_steps"]
        assert a.evaluations == b.evaluations
        np.testing.assert_array_equal(a.pose, b.pose)
        np.testing.assert_array_equal(a.fit.covariance, b.fit.covariance)
        np.testing.assert_array_equal(a.fit.covariance_independent, b.fit.covariance_independent)


def test_a_buffer_made_records_again(talus_calcaneus_128, graphs, monkeypatch):
    """A piece recorded on buffers that an engine replaces is not replayed on them: after the engine's
    buffers are dropped each piece runs as it is first (fewer graphs launched than in the stage before),
    the same results."""
    import core.tracking.likelihood_segments as seg
    from core.tracking.engine_likelihood import likelihood_engine
    from core.tracking.final_stage import final_stage

    r, frame, calls, _ = stage_calls(talus_calcaneus_128)
    res, kw = calls[0]
    kw = {**kw, "others": None}
    monkeypatch.setattr(seg, "SEGMENT_GRAPHS", True)
    first = [final_stage(r, frame, res, **kw) for _ in range(2)]
    n = len(graphs)
    first.append(final_stage(r, frame, res, **kw))
    replayed = len(graphs) - n
    o = kw["options"]
    eng = likelihood_engine(r, bone=kw["bone"], views=kw["views"], highpass_px=o.final_highpass_px,
                            lag_px=o.final_lag_px, others_gain=o.final_others_gain)
    eng._bufs.clear()
    eng._bufs["x"] = None  # (a buffer made: the pieces' stamps stale)
    n = len(graphs)
    again = final_stage(r, frame, res, **kw)
    assert len(graphs) - n < replayed
    for a in first:
        np.testing.assert_array_equal(a.pose, again.pose)
        np.testing.assert_array_equal(a.fit.covariance, again.fit.covariance)


def test_a_switch_changed_records_again(talus_calcaneus_128, graphs, monkeypatch):
    """A module switch a piece reads (the sandwich's stride) changed between stages: the piece is not
    replayed as recorded with the old one; the same results as the calls made one by one with the new."""
    import core.tracking.likelihood_confidence as lc
    import core.tracking.likelihood_segments as seg
    from core.tracking.final_stage import final_stage

    r, frame, calls, _ = stage_calls(talus_calcaneus_128)
    res, kw = calls[1]
    kw = {**kw, "others": None}
    monkeypatch.setattr(seg, "SEGMENT_GRAPHS", True)
    for _ in range(3):
        final_stage(r, frame, res, **kw)
    assert graphs
    monkeypatch.setattr(lc, "SANDWICH_STRIDE", 1)
    got = [final_stage(r, frame, res, **kw) for _ in range(3)]
    monkeypatch.setattr(seg, "SEGMENT_GRAPHS", False)
    plain = final_stage(r, frame, res, **kw)
    for g in got:
        np.testing.assert_array_equal(g.pose, plain.pose)
        np.testing.assert_array_equal(g.fit.covariance, plain.fit.covariance)
