"""core.tracking.smoothing_trial.smooth_trial's written report keeps an earlier report's bones that this call
did not smooth (b941103) — but not a bone whose journal changed since it was smoothed (re-tracked without
smoothing): its smoothed poses would sit beside a journal they no longer describe."""

from __future__ import annotations

import numpy as np
import pytest

from core.geometry.transforms import pose_from_params
from core.study import Study

N = 10
SIGMA = [0.05, 0.05, 0.05, 0.2, 0.2, 0.2]


def _record(tr, b, c, truth, g, frames):
    for f in frames:
        e = g.normal(size=6) * 0.5 * np.r_[SIGMA[:3], np.radians(SIGMA[3:])]
        tr.record_pose(b, f, pose_from_params(e, center=c, base=truth[f]), score=0.8,
                       tracking={"flags": [], "converged": True, "confidence": {"sigma": SIGMA}})


@pytest.fixture
def study(tmp_path):
    """A tiny demo study whose first two bones hold noisy true poses with a confidence σ in every frame."""
    from core.synthetic import make_demo_study
    from core.tracking.bones import bone_model

    out = tmp_path / "study"
    make_demo_study(out, n_frames=N, pixels=32, seed=2, device="cpu", spacing=3.0, tissue_spacing=8.0,
                    calibration_session=False)
    truths = {p.stem: np.load(p) for p in (out / "poses").glob("*.npy")}
    g = np.random.default_rng(0)
    with Study.open(out, mode="w") as st:
        tr = st.trial("walk")
        for b in tr.bones[:2]:
            c = bone_model(st.bone_volume(b), name=b, threshold=200.0, mesh=False).centroid
            _record(tr, b, c, truths[b], g, range(N))
    return out, truths


def test_a_bone_retracked_since_its_smoothing_is_not_kept(study):
    from core.tracking.bones import bone_model
    from core.tracking.smoothing_trial import REPORT_KIND, smooth_trial

    out, truths = study
    with Study.open(out, mode="w") as st:
        a, b = st.trial("walk").bones[:2]
        smooth_trial(st, "walk", [a])
        smooth_trial(st, "walk", [b])
        assert set(st.read_report(REPORT_KIND, "walk")["bones"]) == {a, b}  # (kept: a's journal unchanged)
        c = bone_model(st.bone_volume(a), name=a, threshold=200.0, mesh=False).centroid
        _record(st.trial("walk"), a, c, truths[a], np.random.default_rng(5), range(3, 6))  # a re-tracked
        smooth_trial(st, "walk", [b])
        rep = st.read_report(REPORT_KIND, "walk")
    assert set(rep["bones"]) == {b}
    assert "journal changed" in rep["skipped"][a]
