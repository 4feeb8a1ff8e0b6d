"""The trajectory post-pass's host trims, exact: each frame's residual kept by the neighbours its fit goes
through (core.tracking.flags_fit.MEMO), the table's deltas made in one batch (core.tracking.flags_fit.BATCHED)
and the table of local fits that trajectory_residuals made taken by
the review of the same frames (core.tracking.flags_post.SHARE_TABLE) give the same flags and notes, message
for message, as the pass without them, on tracks with frames turned off the trajectory, frames missing,
every other frame tracked, neighbours outside the run and the search's poses."""

from __future__ import annotations

import numpy as np
import pytest


def _tracks():
    from core.geometry.transforms import pose_from_params
    from core.studies.tracking.trajectory_gaps import CENTER, walking_track

    g = np.random.default_rng(7)
    out = []
    for k in range(10):
        n = int(g.integers(12, 70))
        picks = g.choice(n, size=int(g.integers(0, 6)), replace=False)
        turned = {int(f): float(g.normal(0, 0.5)) for f in picks}

        def shift(i, p, turned=turned):
            if i in turned:
                p[3:] += np.radians(turned[i])

        P = walking_track(n, noise=(0.02, 0.1), seed=100 + k, shift=shift)
        P[g.random(n) < 0.08] = np.nan  # frames without a pose
        frames = np.arange(n) * (2 if k % 3 == 2 else 1)
        judged = np.ones(n, dtype=bool)
        if k % 4 == 3:
            judged[: n // 4] = False  # neighbours outside the run
        S = np.array([pose_from_params(np.r_[g.normal(0, 0.02, 3), np.radians(g.normal(0, 0.1, 3))],
                                       center=CENTER, base=p) if np.all(np.isfinite(p)) else p for p in P])
        out.append((frames, P, judged, S))
    return out


def _review(frames, P, judged, S):
    from core.studies.tracking.trajectory_gaps import CENTER
    from core.tracking.flags_post import trajectory_residuals, trajectory_review

    R = trajectory_residuals(frames, P, CENTER)
    return R, trajectory_review(frames, P, CENTER, judged=judged, searched=S)


@pytest.mark.parametrize("memo,share,batched", [(True, False, False), (False, True, False),
                                                (False, False, True), (True, True, True)])
def test_same_flags_with_the_trims(monkeypatch, memo, share, batched):
    import core.tracking.flags_fit as ff
    import core.tracking.flags_post as fp

    tracks = _tracks()
    monkeypatch.setattr(ff, "MEMO", False)
    monkeypatch.setattr(ff, "BATCHED", False)
    monkeypatch.setattr(fp, "SHARE_TABLE", False)
    before = [_review(*t) for t in tracks]
    monkeypatch.setattr(ff, "MEMO", memo)
    monkeypatch.setattr(ff, "BATCHED", batched)
    monkeypatch.setattr(fp, "SHARE_TABLE", share)
    taken = []
    real = fp._Table

    def table(*a, **k):
        taken.append(False)
        return real(*a, **k)

    monkeypatch.setattr(fp, "_Table", table)
    monkeypatch.setattr(fp, "_TABLES", {})
    after = [_review(*t) for t in tracks]
    flagged = 0
    for (R0, (f0, u0)), (R1, (f1, u1)) in zip(before, after, strict=True):
        assert np.array_equal(R0, R1, equal_nan=True)
        assert f0 == f1 and u0 == u1  # the same frames, the same messages
        flagged += len(f0)
    assert flagged >= 10  # (the tracks have frames to flag)
    # one table a track (trajectory_residuals'), taken by the review where shared
    assert len(taken) == (len(tracks) if share else 2 * len(tracks))
    assert not fp._TABLES or not share


def test_shared_table_taken_once_and_only_for_the_same_inputs(monkeypatch):
    import core.tracking.flags_post as fp
    from core.studies.tracking.trajectory_gaps import CENTER

    frames, P, _, _ = _tracks()[1]
    monkeypatch.setattr(fp, "_TABLES", {})
    fp.trajectory_residuals(frames, P, CENTER)
    assert len(fp._TABLES) == 1
    Q = P.copy()
    Q[3, 0, 3] += 1e-9  # another pose: not taken
    fp.trajectory_review(frames, Q, CENTER)
    assert len(fp._TABLES) == 1
    fp.trajectory_review(frames, P, CENTER, half_window=3)  # other options: not taken
    assert len(fp._TABLES) == 1
    fp.trajectory_review(frames, P, CENTER)
    assert not fp._TABLES  # taken, once
    fp.trajectory_residuals(frames, P, CENTER)
    fp.release_tables()  # (a run's end: one not taken let go)
    assert not fp._TABLES


def test_loop_host_after_last_measures_both_and_puts_the_trims_back():
    import core.tracking.flags_fit as ff
    import core.tracking.flags_post as fp
    from core.studies.tracking.loop_host import after_last

    got = after_last(n_tracks=2, frames=30, rounds=2)
    assert got["flags_and_notes_same"] and set(got["ms_per_bone"]) == {"before", "after"}
    assert all(len(v["rounds"]) == 2 for v in got["ms_per_bone"].values())
    assert ff.MEMO and ff.BATCHED and fp.SHARE_TABLE  # (the defaults again)


def test_three_term_norms_are_numpys():
    """The end frames' calibration (flags_fit.MEMO) sums three squares as (a + b) + c: np.linalg.norm's
    add.reduce over three terms, to the bit (this numpy)."""
    g = np.random.default_rng(5)
    X = g.normal(size=(20000, 6)) * 10.0 ** g.uniform(-6, 3, size=(20000, 1))
    q = X * X
    assert np.array_equal(np.sqrt(q[:, 0] + q[:, 1] + q[:, 2]), np.linalg.norm(X[:, :3], axis=1))
    assert np.array_equal(np.sqrt(q[:, 3] + q[:, 4] + q[:, 5]), np.linalg.norm(X[:, 3:], axis=1))
