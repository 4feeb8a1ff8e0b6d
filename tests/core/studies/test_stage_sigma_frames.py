"""core.studies.tracking.stage_sigma_frames' helpers (no rendering): a stored error rebuilt into its pose, the
bone's recent σ of the unflagged frames before a frame."""

from __future__ import annotations

import numpy as np


def test_rebuild_gives_the_pose_of_the_stored_error():
    from core.geometry.transforms import pose_from_params
    from core.studies.tracking.acceptance_records import pose_errors
    from core.studies.tracking.stage_sigma_frames import _rebuild

    c = np.array([3.0, -2.0, 40.0])
    truth = pose_from_params(np.array([5.0, 1.0, -2.0, 0.3, -0.2, 0.1]), center=c)
    e = np.array([0.05, -0.02, 0.01, 0.7, -0.1, 0.2])
    np.testing.assert_allclose(pose_errors(_rebuild(e, truth, c), truth, c), e, atol=1e-9)


def test_recent_takes_the_unflagged_frames_before():
    from core.studies.tracking.stage_sigma_frames import _recent

    sig = [[0.01 * (g + 1)] * 3 + [0.1] * 3 for g in range(15)]
    sig[3] = None
    t = {"per_frame_sigma": sig, "flag_reasons": {"5": ["uncertain"], "12": ["x"]}}
    got = _recent(t, 12, n=4)
    assert [round(x / np.sqrt(3), 4) for x, _ in got] == [0.09, 0.10, 0.11, 0.12]
    assert len(_recent(t, 6)) == 4 and all(abs(r - 0.1 * np.sqrt(3)) < 1e-9 for _, r in got)
