"""The final stage's noise-free bias by image chain (core.studies.tracking.excess_stage_bias): each
condition's frame, and its search's and stage's errors and their means kept (the registration stubbed: 0.01
and 0.02 mm off the truth in x)."""

from types import SimpleNamespace

import numpy as np
import pytest

from core.studies.tracking import excess_stage_bias as esb


def test_conditions_frames_and_records(monkeypatch):
    import core.tracking.final_stage as fst
    import core.tracking.register as reg
    from core.studies.tracking.acceptance import TrackingScene

    ts = TrackingScene(n_frames=10, pixels=64, spacing=2.0, device="cpu", correction="model", seed=4,
                       phase=(0.0, 0.06))

    def off(pose, mm):
        P = np.array(pose, float)
        P[0, 3] += mm
        return P

    seen = []
    def register(renderer, frame, *, options, initial_pose, **kw):
        seen.append((options.final, frame.n_views))
        return SimpleNamespace(pose=off(initial_pose, 0.01))

    def final_stage(renderer, frame, res, *, options, initial_pose, **kw):
        seen.append((options.final, options.final_highpass_px))
        return SimpleNamespace(pose=off(initial_pose, 0.02), timing={"likelihood_taken": 1})

    monkeypatch.setattr(reg, "register", register)
    monkeypatch.setattr(fst, "final_stage", final_stage)
    out = esb.run(ts=ts, frames=(2, 4), conditions=("trial", "sharp_bones_only"), stored=None)
    assert [r["frame"] for r in out["rows"]] == [2, 4] and out["highpass_px"] == pytest.approx(0.25)
    assert seen[:2] == [(None, 2), ("likelihood", pytest.approx(0.25))]
    for c in ("trial", "sharp_bones_only"):
        assert out["mean"][c]["search"][0] == pytest.approx(0.01, abs=1e-4)
        assert out["mean"][c]["stage"][0] == pytest.approx(0.02, abs=1e-4)
        assert out["rows"][0][c]["taken"] == 1
    with pytest.raises(ValueError, match="condition"):
        esb.frame_for(ts, 2, "blurred")
    frames = {c: esb.frame_for(ts, 2, c) for c in esb.CONDITIONS}
    assert all(len(v) == 2 for v in frames.values())
    for c in ("undistorted", "no_glare", "sharp", "bones_only", "sharp_bones_only"):
        assert not np.allclose(frames[c][0], frames["trial"][0]), c  # each leaves something out
