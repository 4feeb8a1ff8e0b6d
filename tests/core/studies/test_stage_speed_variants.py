"""core.studies.tracking.stage_speed's variants set the flags their docs say: ``plain`` (and
``exact``, ``fast``, as measured against it) is the stage as first measured, the fewer steps'
flags (41d036e's defaults) off too; ``old+<flag>`` sets one of them on the stage before."""

import pytest


def _state():
    import core.tracking.engine_likelihood as el
    import core.tracking.final_stage as fst
    import core.tracking.likelihood_confidence as lc

    return {"STOP_PRED": el.STOP_PRED, "ROBUST_FROM_LAST": fst.ROBUST_FROM_LAST,
            "DEVICE_REGIONS": el.DEVICE_REGIONS, "MEAT_CHUNK": lc.MEAT_CHUNK,
            "DIFF_IMAGES": el.DIFF_IMAGES, "BLOCK_BLUR": el.BLOCK_BLUR}


OLD = {"STOP_PRED": 0.0, "ROBUST_FROM_LAST": False, "DEVICE_REGIONS": False, "MEAT_CHUNK": None}


@pytest.mark.parametrize("name, diff", [("plain", False), ("exact", False), ("fast", True), ("old", None)])
def test_the_stage_before_the_fewer_steps(name, diff):
    from core.studies.tracking.stage_speed import _variant

    before = _state()
    with _variant(name):
        got = _state()
    assert _state() == before  # (restored)
    assert {k: got[k] for k in OLD} == OLD
    if diff is not None:
        assert got["DIFF_IMAGES"] is diff and got["BLOCK_BLUR"] is (name != "plain")


def test_one_fewer_steps_flag_on_the_stage_before():
    from core.studies.tracking.stage_speed import _variant

    with _variant("old+last"):
        got = _state()
    assert got["ROBUST_FROM_LAST"] is True and got["STOP_PRED"] == 0.0 and got["DEVICE_REGIONS"] is False
    with _variant("old+stop4"):
        got = _state()
    assert got["STOP_PRED"] == 4.0 and got["ROBUST_FROM_LAST"] is False


def test_prev_and_nograph():
    """``prev``: the step graphs, the moments' triangle and the sandwich's row-wise autocovariance and
    half-lag meat off; ``nograph``: the step graphs alone."""
    import core.tracking.engine_likelihood as el
    import core.tracking.likelihood_confidence as lc
    from core.studies.tracking.stage_speed import _variant

    def state():
        return (el.STEP_GRAPH, el.MOMENTS_TRI, lc.AUTOCOV_ROWS, lc.MEAT_HALF)

    before = state()
    assert before == (None, True, True, True)
    with _variant("prev"):
        assert state() == (False, False, False, False)
    with _variant("nograph"):
        assert state() == (False, True, True, True)
    assert state() == before


def test_host_table_per_bone_frame():
    import cProfile

    from core.studies.tracking.stage_speed import _host_table

    def work():
        return sum(i * i for i in range(2000))

    p = cProfile.Profile()
    p.enable()
    for _ in range(4):
        work()
    p.disable()
    t = _host_table(p, 2, top=5)
    row = next(x for x in t["inside"] if x["function"].endswith("(work)"))
    assert row["calls"] == 2.0 and row["inside_ms"] >= row["own_ms"] >= 0.0 and len(t["own"]) <= 5


def test_hostprev_and_support_regions():
    """``hostprev``: phase 3's exact host changes off; ``ol<c>``: the support region grown by c σ."""
    import core.tracking.final_stage as fst
    import core.tracking.likelihood_launches as LL
    import core.tracking.roi as roi
    from core.studies.tracking.stage_speed import _known, _variant

    def state():
        return (roi.BOX_CORNERS, LL.BUFFERS_PER_SIZE, fst.REGION_OUTLINE)

    assert state() == (True, True, None)
    with _variant("hostprev"):
        assert state() == (False, False, None)
    with _variant("ol8"):
        assert state() == (True, True, 8.0)
    with _variant("hostprev+ol2.5"):
        assert state() == (False, False, 2.5)
    assert state() == (True, True, None) and _known("ol0") and _known("old") and not _known("olx")
