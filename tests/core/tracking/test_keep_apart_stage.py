"""frame_step._keep_apart (joint tracking with ``contact``) after a final stage: where the contact polish
moves a pose the stage refined (the polish re-optimises the similarity with the interpenetration penalty),
the kept pose is the polish's, so the frame's stage outcome says the stage's pose was not kept
(``likelihood_taken`` 0, a note), not "taken" with the stage's move — the polish and its penetration test
stubbed, no rendering."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np


def test_a_staged_pose_polished_apart_is_no_longer_the_stages(monkeypatch):
    import core.tracking.contact as contact
    from core.tracking.attempt import Attempt
    from core.tracking.frame_step import _keep_apart
    from core.tracking.options import TrackingOptions

    P = np.eye(4)
    polished = np.eye(4)
    polished[0, 3] = 0.3
    monkeypatch.setattr(contact, "penetration_depths", lambda *a, **k: np.array([0.4]))
    monkeypatch.setattr(contact, "polish_with_contact", lambda *a, **k: (polished, 0.9, None, 11, 0.0))
    o = TrackingOptions(mode="joint", contact=True, refine_likelihood=True, confidence=False)
    run = SimpleNamespace(options=o, contacts={0: "me", 1: "other"}, renderer=None, cancel=lambda: False,
                          bones=[SimpleNamespace(centroid=np.zeros(3), outline=None)] * 2)
    timing = {"likelihood_s": 0.1, "likelihood_taken": 1, "likelihood_move_mm": 0.05,
              "likelihood_move_deg": 0.02}
    res = SimpleNamespace(pose=P, score=0.95, fit=None, timing=timing)

    def replace(obj, **kw):  # (a stand-in result: dataclasses.replace's behaviour)
        return SimpleNamespace(**{**vars(obj), **kw})

    monkeypatch.setattr("core.tracking.frame_step._replace", replace)
    a = Attempt(res, [], False, 100, 1.0, None, {"other_s": 0.0})
    _keep_apart(run, None, 0, a, None, [(1, np.eye(4))], o.registration)
    np.testing.assert_array_equal(a.result.pose, polished)
    assert a.result.timing["likelihood_taken"] == 0 and timing["likelihood_taken"] == 1  # (a copy)
    assert a.result.timing["likelihood_move_mm"] == 0.05  # (the stage's move, as it ran)
    assert any("final stage's pose" in n for n in a.notes) and a.evaluations == 111
