"""calibrate_session's steps one by one (as the calibration wizard runs them): the same result as
the one call, a refitted distortion model, frames excluded and labels fixed by hand."""

import numpy as np
import pytest

from core.calibration import session as cs


@pytest.fixture
def steps(memory_session, memory_session_steps):
    """The 384-px session of conftest and its steps run one by one (shared, never changed)."""
    return (memory_session, *memory_session_steps)


def test_steps_give_what_the_one_call_gives(steps, _memory_session_one_call):
    s, setup, dist, beads = steps
    one, one_dist, _ = _memory_session_one_call  # calibrate_session(s) and its distortion step
    # the beads step's input: the step-by-step correction gives the one call's corrected frames
    # (the beads step, labelled once in conftest, is a function of them)
    for v, cam in enumerate(s.cameras):
        for group in ("spiral", "cube"):
            raw = s.read(s.frames(cam, group)[0])
            assert np.array_equal(dist.cameras[v].pipeline(raw), one_dist.cameras[v].pipeline(raw))
    parts = cs.solve_step(setup, dist, beads)
    assert parts.bundle.rms_px == pytest.approx(one.bundle.rms_px, rel=1e-9)
    for a, b in zip(parts.rig, one.rig, strict=True):
        assert np.allclose(a.P, b.P, rtol=1e-9, atol=1e-9) and a.name == b.name
    assert [r["ok"] for r in parts.frames] == [r["ok"] for r in one.frames]


def test_refit_distortion_keeps_the_points_and_the_table(steps):
    _, setup, dist, _ = steps
    new = cs.refit_distortion(setup, dist, 1, "poly(3,3)")
    assert new.cameras[1].grid.spec.label == "poly(3,3)" and new.cameras[0] is dist.cameras[0]
    assert new.cameras[1].grid.table == dist.cameras[1].grid.table
    assert len(new.cameras[1].grid.ideal_uv) == len(dist.cameras[1].grid.ideal_uv)
    with pytest.raises(cs.SessionError, match="distortion: camera"):
        cs.refit_distortion(setup, dist, 0, "poly(40,40)")


def test_exclude_and_relabel(steps):
    _, setup, _, beads = steps
    ok = [k for k, fr in enumerate(beads.frames) if fr.ok]
    ex = cs.exclude_frames(beads, [ok[0]])
    rows, _ = ex.rows()
    assert rows[ok[0]]["reason"] == "excluded by hand" and not rows[ok[0]]["ok"]
    assert len(ex.observations(setup.target, setup.static)[0]) == len(ok) - 1
    with pytest.raises(ValueError, match="frames: indices"):
        cs.exclude_frames(beads, [len(beads.frames)])
    lab = beads.frames[ok[0]].labellings[0]
    i, j = np.flatnonzero(lab.labels >= 0)[:2]
    wrong = cs.relabel(beads, ok[0], 0, int(i), int(lab.labels[j]))  # detection i takes j's bead
    got = wrong.frames[ok[0]].labellings[0]
    assert got.labels[i] == lab.labels[j] and got.labels[j] == -1 and got.manual
    fixed = cs.relabel(cs.relabel(wrong, ok[0], 0, int(i), int(lab.labels[i])), ok[0], 0, int(j),
                       int(lab.labels[j]))
    assert np.array_equal(fixed.frames[ok[0]].labellings[0].labels, lab.labels)
    assert beads.frames[ok[0]].labellings[0] is lab  # the step's result is never changed in place
    assert fixed.rows()[0][ok[0]].get("manual")
    with pytest.raises(ValueError, match="view"):
        cs.relabel(beads, ok[0], 2, 0, 0)
