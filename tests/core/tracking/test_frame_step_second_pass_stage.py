"""Sequential tracking's first-frame second pass with the final stage and without sequential_subtract
(core.tracking.second_pass, frame_step.SECOND_PASS_STAGE_ONLY): the stage alone from the first pass's
pose, checked as the second pass was, the first pass's restart check's verdict kept — the same poses and
flags as the whole pass again, fewer evaluations (ideal 128² views of the talus and calcaneus, Warp's CPU
device, keyframes 5 mm / 5° off). A flagged first pass, or sequential_subtract (the search differs),
registers the second pass whole, as before."""

from __future__ import annotations

from dataclasses import dataclass
from types import SimpleNamespace

import numpy as np

from tests.core.tracking.test_joint_first_frame_keyframes import _off_keyframes


def _options(subtract: bool = False, restarts: int = 4):
    from core.tracking.register import RegistrationOptions
    from core.tracking.trial import TrackingOptions

    reg = RegistrationOptions(bounds=(5.0, 5.0), sigma=(1.0, 1.0), search="newton", final_highpass_px=2.0)
    return TrackingOptions(mode="sequential", sequential_subtract=subtract, verify_restarts=restarts,
                           registration=reg, refine_likelihood=True, trajectory_limit=None)


def _spy(monkeypatch, flag_first_talus: bool = False) -> list:
    """Every registration of the frame step: (bone, pre given, verified, restarts asked, attempt)."""
    import core.tracking.frame_step as fs

    seen = []
    real = fs.register_checked

    def spy(*a, **k):
        got = real(*a, **k)
        if flag_first_talus and a[3] == 0 and not any(s[0] == 0 for s in seen):
            got.flags = [*got.flags, "a flag"]
        seen.append((a[3], k.get("pre") is not None, k.get("verify"), a[7].verify_restarts, got))
        return got

    monkeypatch.setattr(fs, "register_checked", spy)
    return seen


def test_stage_alone_as_the_whole_pass(talus_calcaneus_128, monkeypatch):
    import core.tracking.frame_step as fs
    from core.tracking.trial import track

    sc, models, r, frames = talus_calcaneus_128
    off = _off_keyframes(sc, models)
    assert fs.SECOND_PASS_STAGE_ONLY  # the default
    seen = _spy(monkeypatch)
    new = track(r, models, frames.__getitem__, [0], keyframes=off, options=_options(restarts=2))
    calls = list(seen)
    monkeypatch.setattr(fs, "SECOND_PASS_STAGE_ONLY", False)
    seen.clear()
    old = track(r, models, frames.__getitem__, [0], keyframes=off, options=_options(restarts=2))
    # the first pass as before; the second: the stage's result in place of the search, no restarts
    assert [(b, p, v, n) for b, p, v, n, _ in calls] == [(0, False, True, 2), (1, False, True, 2),
                                                        (0, True, True, 0), (1, True, True, 0)]
    assert [(b, p, n) for b, p, _, n, _ in seen] == [(0, False, 2), (1, False, 2)] * 2
    for a in calls[2:]:
        assert a[4].result.timing["likelihood_taken"] == 1  # the stage ran and was taken
    for m in models:
        n, o = new.results[(m.name, 0)], old.results[(m.name, 0)]
        # the same pose (the search repeated found the first pass's optimum; the stage from it), flags
        np.testing.assert_allclose(n.pose, o.pose, atol=1e-9)
        assert n.flags == o.flags == ()
        assert n.evaluations < 0.6 * o.evaluations  # (4 restarts: talus 1224 / 2409, calcaneus 1128 / 2204)


def test_flagged_first_pass_and_subtraction_register_whole(talus_calcaneus_128, monkeypatch):
    from core.tracking.trial import track

    sc, models, r, frames = talus_calcaneus_128
    off = _off_keyframes(sc, models)
    seen = _spy(monkeypatch, flag_first_talus=True)  # the talus's first pass flagged
    track(r, models, frames.__getitem__, [0], keyframes=off, options=_options(restarts=0))
    assert [(b, p) for b, p, *_ in seen] == [(0, False), (1, False), (0, False), (1, True)]
    seen.clear()
    track(r, models, frames.__getitem__, [0], keyframes=off, options=_options(subtract=True, restarts=0))
    assert [(b, p) for b, p, *_ in seen] == [(0, False), (1, False), (0, False), (1, False)]


def test_stage_pass_without_rendering(monkeypatch):
    """What the stage pass hands the checks (the stage's work alone, no restarts, the first pass's notes
    first) and where it leaves the pass to be registered whole (None)."""
    import core.tracking.final_stage as fst
    from core.tracking.attempt import Attempt
    from core.tracking.options import TrackingOptions
    from core.tracking.register import RegistrationOptions
    from core.tracking.second_pass import stage_pass

    staged = []

    def stage(renderer, frame, res, **k):
        staged.append((res, k))
        return SimpleNamespace(tag="staged")

    monkeypatch.setattr(fst, "final_stage", stage)
    res = _Res(pose=np.eye(4), evaluations=400, time_s=2.0, timing={"render_s": 1.0, "total_s": 2.0})
    kept = Attempt(res, [], False, 400, 2.0, None, {}, notes=("start corrected by restarts",))
    opts = RegistrationOptions(final="likelihood")
    o = TrackingOptions(registration=opts)
    got = []

    def checked(*a, **k):
        got.append((a, k))
        return Attempt(k["pre"][0], [], False, 30, 0.1, None, {}, notes=("n",))

    bone = SimpleNamespace(centroid=np.zeros(3))
    frame = SimpleNamespace(n_views=2)
    a = stage_pass(checked, kept, None, frame, bone, 0, "start", "guess", opts, o, [], None, None, [],
                   verify=True, seed=3)
    assert a.result.tag == "staged" and a.notes == ("start corrected by restarts", "n")
    (base, k), = staged
    assert base.evaluations == 0 and base.time_s == 0 and base.timing == {"render_s": 0.0}
    assert k["initial_pose"] == "start" and k["views"] == (0, 1) and k["options"] is opts
    (args, kw), = got
    assert args[7].verify_restarts == 0 and o.verify_restarts == 4 and kw["verify"] and kw["seed"] == 3
    for bad in (None, Attempt(None, ["outside"], False, 0, 0.0, None, None),
                Attempt(res, ["a flag"], False, 0, 0.0, None, None),
                Attempt(_Res(np.eye(4), 1, 0.0, {"likelihood_s": 0.1}), [], False, 0, 0.0, None, None)):
        assert stage_pass(checked, bad, None, frame, bone, 0, "s", "g", opts, o, [], None, None, []) is None

    def retried(*a, **k):
        return Attempt(k["pre"][0], [], True, 30, 0.1, None, {})

    assert stage_pass(retried, kept, None, frame, bone, 0, "s", "g", opts, o, [], None, None, []).retried


@dataclass
class _Res:
    """A registration result's fields that the stage pass reads and replaces."""

    pose: np.ndarray
    evaluations: int
    time_s: float
    timing: dict
