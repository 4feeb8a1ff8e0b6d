"""likelihood_frames.HELD_FRAME: in joint tracking, where the frame's whole fluence is on the device
(core.tracking.engine_upload, run on Warp's CPU device here), the likelihood stage reads its regions there
instead of uploading its own rows: the same results to the bit (poses, scores, flags, confidences, the
stage's steps and moves), on the ideal 128² talus-calcaneus views, frame 1 tracked jointly from frame 0's
given poses."""

from __future__ import annotations

from tests.core.tracking.test_engine_upload import _track
from tests.core.tracking.test_joint_pipeline import _same


def test_the_stage_reads_the_held_frame_to_the_same_results(talus_calcaneus_128, monkeypatch):
    import core.tracking.engine_upload as eu
    import core.tracking.likelihood_frames as lf

    held = []
    real = lf._FrameRegions._roi_launch

    def spy(self, frame, src, gsrc, li, mask, p):
        up = eu.holding(self.device, frame)
        held.append(up is not None and src is up.src)
        return real(self, frame, src, gsrc, li, mask, p)

    monkeypatch.setattr(lf._FrameRegions, "_roi_launch", spy)
    out = []
    for on in (False, True):
        monkeypatch.setattr(lf, "HELD_FRAME", on)
        monkeypatch.setattr(eu, "_UPLOADS", {})
        monkeypatch.setattr(eu, "_ACTIVE", {})
        held.clear()
        out.append(_track(talus_calcaneus_128, monkeypatch, True))
        assert held and all(held) == on and any(held) == on  # (every stage of the joint frame, or none)
    assert any((r.timing or {}).get("likelihood_taken") for r in out[1].results.values())
    _same(*out)
