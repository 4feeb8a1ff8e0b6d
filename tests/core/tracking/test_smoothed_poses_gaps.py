"""core.tracking.smoothing_trial.smoothed_poses (File → Export…'s *Smoothed poses*,
``talus export --smooth``): a frame inside a bone's tracked span without a pose of its own (a view
missing, the bone outside the field) is NaN in the smoothed poses, as the tracked export and
TrackingResult.filtered_poses leave it; the smoother's prediction there is not written as if the frame
had been tracked. The frames with a pose keep theirs."""

from __future__ import annotations

import numpy as np
import pytest

from core.geometry.transforms import pose_from_params
from core.study import Study

N = 12
GAP = 6
SIGMA = [0.05, 0.05, 0.05, 0.2, 0.2, 0.2]


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    """A tiny demo study whose first bone holds its true poses moved by noise, each with a confidence σ,
    in every frame but GAP (no record there)."""
    from core.synthetic import make_demo_study
    from core.tracking.bones import bone_model

    out = tmp_path_factory.mktemp("smoothed_gaps") / "study"
    make_demo_study(out, n_frames=N, pixels=32, seed=2, device="cpu", spacing=3.0, tissue_spacing=8.0,
                    calibration_session=False)
    truths = {p.stem: np.load(p) for p in (out / "poses").glob("*.npy")}
    g = np.random.default_rng(0)
    with Study.open(out, mode="w") as st:
        tr = st.trial("walk")
        b = tr.bones[0]
        c = bone_model(st.bone_volume(b), name=b, threshold=200.0, mesh=False).centroid
        for f in range(N):
            if f == GAP:
                continue
            e = g.normal(size=6) * 0.5 * np.r_[SIGMA[:3], np.radians(SIGMA[3:])]
            tr.record_pose(b, f, pose_from_params(e, center=c, base=truths[b][f]), score=0.8,
                           tracking={"flags": [], "converged": True, "confidence": {"sigma": SIGMA}})
    return out


def test_a_frame_without_a_pose_stays_nan(study):
    from core.tracking.smoothing_trial import smooth_trial, smoothed_poses

    with Study.open(study) as st:
        tr = st.trial("walk")
        b = tr.bones[0]
        assert np.isnan(tr.poses(b)[GAP]).all()  # (the scenario: no record at GAP)
        got = smoothed_poses(st, "walk", [b])[b]
        rep = smooth_trial(st, "walk", [b], write=False)
    ok = np.isfinite(got).all(axis=(1, 2))
    assert not ok[GAP]
    assert ok[[f for f in range(N) if f != GAP]].all()
    # the report keeps the smoother's prediction there, its weight 0 (not measured)
    entry = rep["bones"][b]
    k = GAP - entry["frames"][0]
    assert entry["poses"][k] is not None and entry["weights"][k] == 0.0
