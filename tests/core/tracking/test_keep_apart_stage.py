"""core.tracking.keep_apart (joint tracking with ``contact``) after a final stage, the polish, its
penetration test and the stage stubbed (no rendering): where the contact polish moves a pose the stage
refined (the polish re-optimises the similarity with the interpenetration penalty), the polished pose
stands and the frame's stage outcome says the stage's pose was not kept (``likelihood_taken`` 0, a note),
not "taken" with the stage's move; with RESTAGE (off by default) it goes through the stage once more and the
stage's pose is kept where it comes no deeper into a neighbour. Last, through the tracker, unstubbed: the
stage run again goes back as deep as before (why RESTAGE is off)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest


def _moved(x: float) -> np.ndarray:
    P = np.eye(4)
    P[0, 3] = x
    return P


POLISHED = _moved(0.3)


@pytest.fixture
def scene(monkeypatch):
    """A run of two bones with contact and the stage, bone 0's staged pose 0.4 mm into bone 1 (the depth
    a stub: the pose's x where it is the registered pose's, else ``depth_at``'s), its polish stubbed."""
    import core.tracking.contact as contact
    import core.tracking.keep_apart as ka
    from core.tracking.attempt import Attempt
    from core.tracking.options import TrackingOptions

    depth_at = {0.0: 0.4, 0.3: 0.0}
    monkeypatch.setattr(contact, "penetration_depths",
                        lambda me, P, nb, margin=0.0: np.array([depth_at[round(float(P[0][0, 3]), 6)]]))
    polish = (POLISHED, 0.9, "polish fit", 11, 0.0)
    monkeypatch.setattr(contact, "polish_with_contact", lambda *a, **k: polish)

    def replace(obj, **kw):  # (a stand-in result: dataclasses.replace's behaviour)
        return SimpleNamespace(**{**vars(obj), **kw})

    monkeypatch.setattr(ka, "_replace", replace)
    monkeypatch.setattr(ka, "RESTAGE", True)  # (off by default: these tests are of it)
    o = TrackingOptions(mode="joint", contact=True, refine_likelihood=True, confidence=False)
    run = SimpleNamespace(options=o, contacts={0: "me", 1: "other"}, renderer=None, cancel=lambda: False,
                          bones=[SimpleNamespace(centroid=np.zeros(3), outline=None)] * 2)
    timing = {"likelihood_s": 0.1, "likelihood_steps": 3, "likelihood_taken": 1, "likelihood_move_mm": 0.05,
              "likelihood_move_deg": 0.02}
    res = SimpleNamespace(pose=np.eye(4), score=0.95, fit=None, timing=timing, evaluations=100)
    a = Attempt(res, [], False, 100, 1.0, None, {"other_s": 0.0, "likelihood_s": 0.1, "likelihood_steps": 3})
    return SimpleNamespace(ka=ka, run=run, a=a, o=o, timing=timing, depth_at=depth_at)


def _stage_to(monkeypatch, x: float, calls: list, taken: int = 1):
    import core.tracking.final_stage as fst

    def final_stage(renderer, frame, res, *, bone, initial_pose, center, options, views, others=None):
        calls.append((res, initial_pose, others))
        t = {**res.timing, "likelihood_s": 0.05, "likelihood_steps": 4, "likelihood_taken": taken,
             "likelihood_move_mm": abs(x - 0.3), "likelihood_move_deg": 0.0}
        return SimpleNamespace(**{**vars(res), "pose": _moved(x) if taken else res.pose, "timing": t,
                                  "fit": "stage fit" if taken else res.fit,
                                  "evaluations": res.evaluations + 20})

    monkeypatch.setattr(fst, "final_stage", final_stage)


def test_the_stage_again_from_the_polished_pose_kept_where_no_deeper(scene, monkeypatch):
    calls: list = []
    _stage_to(monkeypatch, 0.32, calls)
    scene.depth_at[0.32] = 0.0
    frame = SimpleNamespace(n_views=2)
    scene.ka.keep_apart(scene.run, frame, 0, scene.a, "others", [(1, np.eye(4))], scene.o.registration)
    a = scene.a
    (res, base, others), = calls
    np.testing.assert_array_equal(res.pose, POLISHED)
    np.testing.assert_array_equal(base, POLISHED)
    assert others == "others" and "likelihood_s" not in res.timing  # (the first stage's work left out)
    np.testing.assert_array_equal(a.result.pose, _moved(0.32))
    assert a.result.timing["likelihood_taken"] == 1 and a.result.fit == "stage fit"
    assert a.evaluations == 100 + 11 + 20
    assert a.timing["likelihood_s"] == pytest.approx(0.15) and a.timing["likelihood_steps"] == 7
    assert a.timing["other_s"] >= 0 and any("its pose kept" in n for n in a.notes)
    assert scene.timing["likelihood_taken"] == 1  # (the registration's own timing not changed)


def test_a_stage_pose_deeper_into_a_neighbour_leaves_the_polished_pose(scene, monkeypatch):
    calls: list = []
    _stage_to(monkeypatch, 0.05, calls)
    scene.depth_at[0.05] = 0.2
    scene.ka.keep_apart(scene.run, SimpleNamespace(n_views=2), 0, scene.a, None, [(1, np.eye(4))],
                        scene.o.registration)
    a = scene.a
    np.testing.assert_array_equal(a.result.pose, POLISHED)
    assert a.result.timing["likelihood_taken"] == 0 and a.result.fit == "polish fit"
    assert a.result.timing["likelihood_move_mm"] == 0.05  # (the first stage's move, as it ran)
    assert a.evaluations == 131 and a.timing["likelihood_steps"] == 7  # (its work counted all the same)
    assert any("0.20 mm into a neighbour: the polished pose kept" in n for n in a.notes)


def test_a_staged_pose_polished_apart_without_restage_is_no_longer_the_stages(scene, monkeypatch):
    monkeypatch.setattr(scene.ka, "RESTAGE", False)
    scene.ka.keep_apart(scene.run, None, 0, scene.a, None, [(1, np.eye(4))], scene.o.registration)
    a = scene.a
    np.testing.assert_array_equal(a.result.pose, POLISHED)
    assert a.result.timing["likelihood_taken"] == 0 and scene.timing["likelihood_taken"] == 1  # (a copy)
    assert a.result.timing["likelihood_move_mm"] == 0.05  # (the stage's move, as it ran)
    assert any("final stage's pose" in n for n in a.notes) and a.evaluations == 111


def test_an_unstaged_pose_is_polished_without_a_stage(scene, monkeypatch):
    calls: list = []
    _stage_to(monkeypatch, 0.32, calls)
    scene.a.result.timing = {}
    scene.ka.keep_apart(scene.run, None, 0, scene.a, None, [(1, np.eye(4))], scene.o.registration)
    assert not calls and scene.a.evaluations == 111
    np.testing.assert_array_equal(scene.a.result.pose, POLISHED)
    assert not any("final stage" in n for n in scene.a.notes)


def test_a_stage_that_takes_no_move_leaves_the_polished_pose(scene, monkeypatch):
    calls: list = []
    _stage_to(monkeypatch, 0.3, calls, taken=0)
    scene.ka.keep_apart(scene.run, SimpleNamespace(n_views=2), 0, scene.a, None, [(1, np.eye(4))],
                        scene.o.registration)
    a = scene.a
    assert len(calls) == 1 and a.result.timing["likelihood_taken"] == 0 and a.evaluations == 131
    assert any("polished with the similarity" in n for n in a.notes)


def test_joint_tracking_with_contact_and_the_stage(talus_calcaneus_128, monkeypatch):
    """Unstubbed, through the tracker (ideal 128² talus-calcaneus, frame 1 from frame 0's given poses, a 6 mm
    margin so that the calcaneus is polished apart from the talus): by default the polished pose stands
    (``likelihood_taken`` 0, the note); with RESTAGE the stage run again from it goes back as deep into the
    talus as the staged pose was (it knows no penalty: why RESTAGE is off) and the polished pose stands."""
    import core.tracking.keep_apart as ka
    from core.tracking.register import RegistrationOptions
    from core.tracking.trial import TrackingOptions, track

    sc, models, r, imgs = talus_calcaneus_128
    keys = {m.name: {0: sc.poses(0)[k]} for k, m in enumerate(models)}
    reg = RegistrationOptions(bounds=(5.0, 5.0), sigma=(1.0, 1.0), search="newton")
    o = TrackingOptions(mode="joint", verify_restarts=0, registration=reg, refine_likelihood=True,
                        contact=True, contact_margin_mm=6.0)

    def polished():
        res = track(r, models, imgs.__getitem__, [0, 1], keyframes=keys, skip=keys, options=o)
        out = [(fr, next(n for n in fr.notes if n.startswith("contact:"))) for fr in res.results.values()
               if any(n.startswith("contact:") for n in fr.notes)]
        assert out
        return out

    assert not ka.RESTAGE
    for fr, note in polished():
        assert note.endswith("the final stage's pose polished with the similarity")
        assert fr.timing["likelihood_taken"] == 0
    monkeypatch.setattr(ka, "RESTAGE", True)
    for fr, note in polished():
        assert "the final stage run again from the polished pose came" in note
        before = float(note.split(" mm interpenetration")[0].split()[-1])
        back = float(note.split("pose came ")[1].split()[0])
        assert abs(back - before) <= 0.02 and fr.timing["likelihood_taken"] == 0
