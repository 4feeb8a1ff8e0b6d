"""Shared fixtures of the calibration tests: a full-size rig (projections only, nothing
rendered), and one small rendered calibration session, calibrated once for the whole run (whole
and step by step)."""

import numpy as np
import pytest

from core.synthetic import foot_rig


@pytest.fixture(scope="session")
def rig():
    """The default foot rig at 1024 px (0.29 mm pixels); used for projected points only."""
    return foot_rig(seed=0, pixels=1024)


@pytest.fixture(scope="session")
def sizes(rig):
    return [(c.width, c.height) for c in rig]


@pytest.fixture
def rng():
    return np.random.default_rng(1234)


# ------------------------------------------------------------- one small session, calibrated once
# Labelling the session's beads is the expensive part of a session calibration (~20 s of CPU on a
# 2-core machine); the files that need a calibrated session share this one for the whole test run.
# Tests read these objects and never change them (the steps' edits return copies).
@pytest.fixture(scope="session")
def memory_session():
    """An in-memory session at 384 px: 10 spiral frames, the static cube, 1 grid frame per view."""
    from core.studies.calibration.memory_session import make_memory_session

    return make_memory_session(pixels=384, n_spiral=10, n_grid=1, n_flat=4, n_dark=2, seed=3)


@pytest.fixture(scope="session")
def _memory_session_one_call(memory_session):
    """:func:`~core.calibration.session.calibrate_session` of :data:`memory_session`, and the
    distortion step and beads step it made on the way (spied, not changed)."""
    from core.calibration import session as cs

    seen = {}
    beads_step = cs.beads_step

    def spy(setup, dist, **kw):
        seen["dist"], seen["beads"] = dist, beads_step(setup, dist, **kw)
        return seen["beads"]

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(cs, "beads_step", spy)
        cal = cs.calibrate_session(memory_session)
    return cal, seen["dist"], seen["beads"]


@pytest.fixture(scope="session")
def memory_session_calibrated(_memory_session_one_call):
    """:func:`core.calibration.session.calibrate_session` of :data:`memory_session` (the one call)."""
    return _memory_session_one_call[0]


@pytest.fixture(scope="session")
def memory_session_steps(memory_session, _memory_session_one_call):
    """``(setup, distortion step, beads step)`` of :data:`memory_session` run one by one as the
    calibration wizard runs them. The beads step, a function of the corrected frames alone, is the
    one call's (labelling the beads twice would double the cost): test_calibration_session_steps
    checks that the step-by-step distortion step corrects the frames exactly as the one call's."""
    from core.calibration import session as cs

    setup = cs.prepare(memory_session)
    dist = cs.distortion_step(setup, cs.flatfield_step(setup))
    return setup, dist, _memory_session_one_call[2]
