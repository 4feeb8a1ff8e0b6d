"""The tracking benchmark's ``final`` option (``core.studies.tracking.benchmark``): the runs of a
list of final stages, in order, on the same scene. The stage itself runs in its own tests."""

import pytest


def test_final_runs_keys_and_options_in_the_listed_order():
    from core.studies.tracking.benchmark import _final_runs
    from core.tracking.trial import TrackingOptions

    o = TrackingOptions(mode="joint")
    runs = _final_runs("none, likelihood,likelihood,none", o)
    assert [k for k, _ in runs] == ["", "_likelihood", "_likelihood_2", "_2"]
    assert [oo.refine_likelihood for _, oo in runs] == [False, True, True, False]
    assert runs[1][1].registration.final == "likelihood" and runs[0][1] is o
    assert [k for k, _ in _final_runs("none", o)] == [""]
    with pytest.raises(ValueError, match="final"):
        _final_runs("none,ml", None)


def test_run_refuses_an_unknown_final_stage_before_making_the_scene():
    from core.studies.tracking.benchmark import run

    with pytest.raises(ValueError, match="final"):
        run(quick=True, device="cpu", frames=2, pixels=64, cases="one", final="likelihood,plain")


def test_likelihood_full_runs_the_stage_after_the_search_to_its_own_tolerance():
    import core.tracking.register_options as ro
    from core.studies.tracking.benchmark import _final_runs, _search_tol
    from core.tracking.trial import TrackingOptions

    runs = _final_runs("likelihood_full,likelihood", TrackingOptions(mode="joint"))
    assert [k for k, _ in runs] == ["_likelihood_full", "_likelihood"]
    assert all(oo.refine_likelihood for _, oo in runs)
    kept = ro.STAGE_SEARCH_TOL
    with _search_tol("likelihood_full") as tol:
        assert tol is None and ro.STAGE_SEARCH_TOL is None
    assert ro.STAGE_SEARCH_TOL == kept
    with _search_tol("likelihood") as tol:
        assert tol == kept
    import core.tracking.register as reg

    with _search_tol("likelihood_first") as tol:
        assert tol == "first" and reg.STAGE_FIRST
    assert not reg.STAGE_FIRST
