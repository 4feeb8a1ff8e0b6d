"""The trajectory check's shared arithmetic (core.tracking.flags_fit.SHARED: each frame offset's deltas
computed once for the calibration of a trial's end frames, the fits' weights kept for every table) is
exact: the same residuals to the bit, and the same flags and notes, as the arithmetic before."""

from __future__ import annotations

import numpy as np
import pytest

from core.tracking import flags_fit
from core.tracking.flags_fit import _Table
from core.tracking.flags_post import apply_trajectory_flags
from core.tracking.results import FrameResult, TrackingResult
from tests.core.tracking.track_helpers import C, walking_track


def _track(seed, n, spikes):
    """The tests' walking track (0.01 mm / 0.05 deg noise per axis), frames ``spikes`` turned and moved
    (a frame off by 0.3-2 deg, 0.05-0.3 mm, some two in a row, some at the trial's ends)."""
    rng = np.random.default_rng(1000 + seed)
    off = {int(f): (rng.uniform(0.05, 0.3), rng.uniform(0.3, 2.0)) for f in spikes}

    def shift(k, p):
        if k in off:
            p[0] += off[k][0]
            p[5] += np.radians(off[k][1])

    return walking_track(n, (0.01, 0.05), seed, shift)


def _cases():
    """(frames, poses, own flags, neighbours): whole tracks, every 2nd frame tracked, frames missing and
    flagged by the per-frame checks, and a range with the journal's neighbours around it."""
    out = []
    for seed in range(4):
        n = 60
        rng = np.random.default_rng(seed)
        spikes = [*rng.choice(n, 5, replace=False), 0, n - 1, 30, 31]
        P = _track(seed, n, spikes)
        own = {int(f) for f in rng.choice(n, 3, replace=False)}
        P[int(rng.integers(5, n - 5))] = np.nan
        out.append((np.arange(n), P, own, None))
        out.append((np.arange(0, 2 * n, 2)[: n // 2], P[: n // 2], set(), None))
        near = {f: P[f] for f in range(n) if not 20 <= f < 40}
        out.append((np.arange(20, 40), P[20:40], set(), near))
    return out


def _run(frames, P, own, near):
    res = {}
    for k, f in enumerate(int(f) for f in frames):
        pose = P[k] if np.isfinite(P[k]).all() else None
        res[("b", f)] = FrameResult("b", f, pose, 0.8, 10, 0.0, f not in own, ("lost",) if f in own else ())
    run = TrackingResult(("b",), tuple(int(f) for f in frames), res, "complete", 0.0)
    got, changed = apply_trajectory_flags(run, {"b": C}, neighbours={"b": near} if near else None)
    return ([(k, r.flags, r.notes) for k, r in sorted(got.results.items())],
            sorted((r.bone, r.frame) for r in changed))


@pytest.fixture
def shared(monkeypatch):
    def use(on):
        monkeypatch.setattr(flags_fit, "SHARED", on)
        flags_fit._WEIGHTS.clear()
    yield use
    flags_fit._WEIGHTS.clear()


def test_the_same_flags_and_notes_with_the_arithmetic_shared(shared):
    cases = _cases()
    shared(False)
    before = [_run(*c) for c in cases]
    shared(True)
    now = [_run(*c) for c in cases]
    assert now == before
    flagged = sum(1 for flags, _ in before for _, f, _ in flags if f and f[0] != "lost")
    assert flagged >= 20  # flags to compare
    again = [_run(*c) for c in cases]  # the weights kept from the runs before
    assert again == before


def test_the_same_residuals_to_the_bit(shared):
    for frames, P, _, _ in _cases():
        ok = np.isfinite(P.reshape(len(P), -1)).all(axis=1)
        got = []
        for on in (False, True):
            shared(on)
            t = _Table(np.asarray(frames), P, ok, C, 4, 2, True)
            t.calibrate(np.array([0.01, 0.05]))
            use = ok.copy()
            use[::7] = False  # fits with frames left out: other offsets
            got.append(np.array([t.residual(i, u) for u in (ok, use) for i in range(len(P))]))
        assert np.array_equal(got[0], got[1], equal_nan=True)


def test_the_calibrations_median_is_numpys_to_the_bit():
    rng = np.random.default_rng(0)
    for m in [*range(1, 12), 99, 100, 257]:
        for ties in (False, True):
            S = np.abs(rng.normal(size=(m, 2))) * 0.05
            S = np.round(S, 3) if ties else S
            assert np.array_equal(flags_fit._median(S), np.median(S, axis=0))
    S[0, 1] = np.nan
    assert np.array_equal(flags_fit._median(S), np.median(S, axis=0), equal_nan=True)
