"""The silent-failure candidate checks' residuals (core.studies.tracking.silent_checks): a short run
of frames off together hides from the fit through its nearest neighbours and shows once they are
left out of it."""

from __future__ import annotations

import numpy as np

from core.studies.tracking.silent_checks import _axis_scale, _norm_scale, auc, block_residuals
from tests.core.tracking.track_helpers import C, walking_track


def _track(n=40, noise=(0.01, 0.05), seed=1, run=(), deg=0.0):
    def shift(k, p):
        if k in run:
            p[5] += np.radians(deg)

    return walking_track(n, noise, seed, shift)


def test_a_three_frame_run_shows_once_its_neighbours_leave_the_fit():
    P = _track(run=(20, 21, 22), deg=0.4)
    use = np.ones(len(P), dtype=bool)
    near = _norm_scale(block_residuals(P, use, C, gap=0), use)
    wide = _norm_scale(block_residuals(P, use, C, gap=2), use)
    assert wide[21] > 4 and wide[21] > 1.5 * near[21]
    # the residual is signed per axis, in degrees: the run's middle frame about z
    R = block_residuals(P, use, C, gap=2)
    assert R[21, 5] > 0.2 and abs(R[21, 3]) < 0.1
    assert np.argmax(_axis_scale(R, use)) in (20, 21, 22)


def test_noise_free_tracks_fit_and_the_ends_are_extrapolated():
    P = _track(noise=(0.0, 0.0))
    use = np.ones(len(P), dtype=bool)
    R = block_residuals(P, use, C, gap=2)
    assert np.all(np.isfinite(R))  # the first and last frames from one side
    assert np.abs(R).max() < 0.02 and np.abs(R[8:-8]).max() < 0.002
    use[10] = False
    assert np.isnan(block_residuals(P, use, C)[10]).all()


def test_auc():
    assert auc(np.array([2.0, 3.0]), np.array([0.0, 1.0])) == 1.0
    assert auc(np.array([1.0]), np.array([1.0])) == 0.5
    assert np.isnan(auc(np.array([]), np.array([1.0])))


def test_the_kept_runs_read_back_and_the_near_rule_flags_frame_81():
    """The benchmark's per-frame state (seed 0, joint: the acceptance trial) read back from its JSON:
    the trajectory check left tibia frame 81 (4.45x its bound) silent; with its rule for frames next
    to flagged ones it flags it."""
    from pathlib import Path

    from core.studies.tracking.silent_checks import load, trajectory_counts

    path = str(Path(__file__).resolve().parents[3] / "resources" / "benchmarks"
               / "tracking_silent_checks_per_frame_h100.json") + "#0_joint"
    tibia = load(path)["tibia"]
    assert np.flatnonzero(tibia["over"]).tolist() == [41, 50, 79, 81, 89]
    assert np.flatnonzero(tibia["over"] & ~tibia["flags"]).tolist() == [81]  # as the tracker left it
    later = {"along": None, "one_sided": False, "ends": False}  # rules made after it (trajectory_silent)
    before = trajectory_counts([path], near=None, **later)["runs"][path]
    after = trajectory_counts([path], **later)["runs"][path]
    assert before["tibia"]["silent"] == [81] and after["tibia"]["silent"] == []
    assert len(after["tibia"]["good_flagged"]) - len(before["tibia"]["good_flagged"]) == 1


def test_the_kept_runs_give_the_benchmarks_counts_without_and_with_the_near_rule():
    """The trajectory check run afresh on the six kept runs (seeds 0-2, joint and sequential) gives
    the counts tracking_silent_checks_h100.json stores, which the README and flags_post.NEAR quote:
    frames over 4x left silent 20 -> 17 of 39, good bone-frames flagged 89 -> 100 of 1761 (the check as
    it was before frames whose neighbours are all flagged were judged: ``reach=None``); judging them
    (flags_post.REACH) changes no flag here: of the 11 such frames one (seed 1's joint tibia frame 14) lies
    between frames judged good and passes, 10 at a trial's end are noted unchecked. The pair rule
    (flags_post.PAIR, 'pair=None' before it) flags two good frames more."""
    import json
    from pathlib import Path

    from core.studies.tracking.silent_checks import trajectory_counts

    bench = Path(__file__).resolve().parents[3] / "resources" / "benchmarks"
    stored = json.loads((bench / "tracking_silent_checks_h100.json").read_text())["trajectory_check"]
    kept = str(bench / "tracking_silent_checks_per_frame_h100.json")
    runs = [f"{kept}#{s}_{m}" for s in range(3) for m in ("joint", "sequential")]
    for near, total in ((None, (39, 20, 1761, 89)), (0.7, (39, 17, 1761, 100))):
        got = trajectory_counts(runs, near=near, reach=None, pair=None, along=None, one_sided=False,
                                ends=False)
        assert tuple(got["total"][k] for k in ("over", "silent", "good", "good_flagged")) == total
        assert got["total"] == stored[str(near)]["total"]
        for r in runs:  # per run and bone, as stored under the dumps' names
            assert got["runs"][r] == stored[str(near)]["runs"][f"d_{r.rsplit('#', 1)[1]}_newton.npz"]
    now = trajectory_counts(runs, pair=None, along=None, one_sided=False, ends=False)["total"]
    assert tuple(now[k] for k in ("over", "silent", "good", "good_flagged")) == (39, 17, 1761, 100)
    now = trajectory_counts(runs, along=None, one_sided=False, ends=False)["total"]  # pairs: calcaneus 92-93
    assert tuple(now[k] for k in ("over", "silent", "good", "good_flagged")) == (39, 17, 1761, 102)
    now = trajectory_counts(runs, ends=False)["total"]  # frames next to flagged ones the same way, one-sided
    assert tuple(now[k] for k in ("over", "silent", "good", "good_flagged")) == (39, 17, 1761, 125)
    now = trajectory_counts(runs)["total"]  # the trial's ends fitted through the shifted window (flags_ends)
    assert tuple(now[k] for k in ("over", "silent", "good", "good_flagged")) == (39, 17, 1761, 115)
