"""The acceptance study's ``--seed`` (another synthesis of the trial; the default the trial as it was)
and what its JSON says of each silent frame (core.studies.tracking.acceptance_goals.silent_details)."""

import json
from types import SimpleNamespace

import numpy as np
import pytest

from core.studies.tracking import acceptance
from core.studies.tracking.acceptance_goals import silent_details
from core.tracking.flags_post import FLAG
from tests.core.tracking.track_helpers import C, walking_track


def test_the_default_scene_is_the_acceptance_trial_as_it_was():
    """No seed given: the trial's scene of before ``--seed`` (truth and frames of a 64² three-frame
    version, numbers taken from the study before the option), and seed 3 another one."""
    ts = acceptance.tracking_scene(quick=True, device="cpu", n_frames=3, pixels=64, correction="model")
    T = np.array([ts.truth(f) for f in range(3)])
    F = np.array(ts.frames(2))
    assert ts._seed == 0
    assert float(T.sum()) == pytest.approx(-280.458010484704, rel=1e-12)
    assert float(np.abs(T).sum()) == pytest.approx(459.25696273760497, rel=1e-12)
    assert float(F.sum()) == pytest.approx(2837.32373046875, rel=1e-6)
    assert float((F ** 2).sum()) == pytest.approx(1792.649658203125, rel=1e-6)
    assert float(F[0, 32, 32]) == pytest.approx(0.10877631604671478, rel=1e-6)
    assert float(F[1, 20, 40]) == pytest.approx(0.7300496101379395, rel=1e-6)
    other = acceptance.TrackingScene(n_frames=3, pixels=64, spacing=2.0, device="cpu", seed=3)
    assert other._seed == 3 and not np.allclose(np.array([other.truth(f) for f in range(3)]), T)


def test_main_hands_the_seed_to_the_scene_and_records_it(monkeypatch, tmp_path):
    import core.io.atomic

    calls, scenes = [], []
    monkeypatch.setattr(acceptance, "tracking_scene", lambda **kw: scenes.append(kw) or "scene")
    monkeypatch.setattr(acceptance, "run", lambda **kw: calls.append(kw) or {"tracking": {}})
    monkeypatch.setattr(core.io.atomic, "print_json", lambda obj, out=None: out and
                        (tmp_path / "o.json").write_text(json.dumps(obj)))
    acceptance.main(["--quick"])
    acceptance.main(["--quick", "--seed", "3"])
    assert [c["seed"] for c in calls] == [0, 3]
    acceptance.main(["--quick", "--seed", "4", "--mode", "joint,sequential", "--out",
                     str(tmp_path / "o.json")])
    assert scenes[-1]["seed"] == 4 and [c["ts"] for c in calls[2:]] == ["scene", "scene"]
    assert json.loads((tmp_path / "o.json").read_text())["seed"] == 4


def _result(P, flags, sigma=(0.01, 0.01, 0.01, 0.05, 0.05, 0.05)):
    return SimpleNamespace(results={("talus", f): SimpleNamespace(
        pose=P[f], flags=flags.get(f, ()), score=0.9, converged=True, retried=False, notes=(),
        confidence={"sigma": list(sigma)}) for f in range(len(P))})


def test_silent_details_give_the_frames_error_neighbours_and_trajectory_residuals():
    """A walking track, frame 20 moved 0.3 mm (silent), frame 21 flagged by the trajectory pass and
    frame 5 by a frame check: frame 20's error and neighbours, the flagged frames near it, and its
    residual against the fit with frame 21 in it (the pass's first judgement) and without."""
    from core.studies.tracking.acceptance import pose_errors

    P = walking_track(40, shift=lambda k, p: p.__setitem__(0, p[0] + 0.3) if k == 20 else None)
    T = walking_track(40, noise=(0.0, 0.0))
    errors = {f: pose_errors(P[f], T[f], C) for f in range(40)}
    res = _result(P, {21: (f"{FLAG} (0.1 mm)",), 5: ("score drop",)})
    bound = {"rms_mm": 0.02, "rms_deg": 0.1}
    (d,) = silent_details(res, "talus", C, errors, bound, [20])
    json.dumps(d, allow_nan=False)
    assert d["frame"] == 20 and d["error_mm"] == pytest.approx(0.3, abs=0.05)
    assert d["over_bound"][0] == pytest.approx(d["error_mm"] / 0.02, abs=0.01)
    assert d["flagged_within_window"] == [21]
    assert sorted(d["neighbours_over_bound"]) == ["18", "19", "21", "22"]
    assert all(v < 4 for v in d["neighbours_over_bound"].values())
    assert d["sigma"] == [0.01, 0.01, 0.01, 0.05, 0.05, 0.05] and d["score"] == 0.9 and d["converged"]
    assert d["stage"] is None and d["stage_move_mm"] is None  # no final stage
    tr = d["trajectory"]
    assert 0.003 < tr["median_mm"] < 0.05 and tr["limit_x_median"] == 2.5
    assert tr["last"]["x_median"][0] > 2.5 and tr["first"]["mm"] != tr["last"]["mm"]
    assert tr["last"]["mm"] == pytest.approx(tr["last"]["x_median"][0] * tr["median_mm"], rel=0.02)
    assert silent_details(res, "talus", C, errors, bound, []) == []


def test_run_records_the_seed_the_silent_frames_and_the_flagged_frames_reasons(monkeypatch):
    """run() with the tracker replaced by the true poses 0.01 mm off, the talus's frame 6 2 mm off
    and unflagged (with a note), frame 3 2 mm off and flagged (with a note), frame 8 flagged though
    good: its config has the seed, frame 6 is silent with its details; the record keeps frames 3 and
    8's reasons, the goals list frames 3 and 6 over 4x the bound, flagged or not and why (64², 10
    frames)."""
    import core.tracking.trial as trial_mod
    from core.studies.tracking.acceptance_goals import regoal
    from core.studies.tracking.acceptance_records import NOTE
    from core.tracking.results import FrameResult, TrackingResult

    ts = acceptance.TrackingScene(n_frames=10, pixels=64, spacing=2.0, device="cpu", names=("talus",))
    flags = {3: ("score drop",), 8: (f"{FLAG} (1.2x)",)}
    notes = {3: ("start corrected by restarts",), 6: ("unchecked (its neighbours flagged)",)}

    def track(renderer, models, frames, order, keyframes=None, options=None):
        res = {}
        for f in order:
            P = ts.truth(f)[0].copy()
            P[0, 3] += 2.0 if f in (3, 6) else 0.01
            res[("talus", f)] = FrameResult("talus", f, P, 0.9, 1, 0.0, True, flags=flags.get(f, ()),
                                            notes=notes.get(f, ()))
        return TrackingResult(("talus",), tuple(order), res, "complete", 0.0)

    monkeypatch.setattr(trial_mod, "track", track)
    out = acceptance.run(ts=ts, mode="joint", capture_trials=0)
    assert out["config"]["seed"] == 0
    t = out["tracking"]["talus"]
    ob = t["over_4x_bound"]
    assert ob["frames"] == [3, 6] and ob["silent_frames"] == [6]
    (d,) = ob["silent_details"]
    assert d["frame"] == 6 and d["error_mm"] == pytest.approx(2.0, abs=1e-6) and d["sigma"] is None
    assert t["flagged_frames"] == [3, 8]
    assert t["flag_reasons"] == {"3": ["score drop", NOTE + "start corrected by restarts"],
                                 "8": [f"{FLAG} (1.2x)"]}
    assert out["goals"]["talus"]["over_4x_frames"] == [
        {"frame": 3, "flagged": True, "reasons": ["score drop", NOTE + "start corrected by restarts"]},
        {"frame": 6, "flagged": False, "reasons": [NOTE + "unchecked (its neighbours flagged)"]}]
    sig = t["per_frame_signals"]  # every frame's, flagged or not, in frames_with_pose's order
    assert sig["score"] == [0.9] * 10 and sig["stage"] == [None] * 10
    assert sig["search_error"] == [None] * 10 == sig["stage_move"]  # no stage: the pose is the search's
    from core.studies.tracking.acceptance_records import stored_signals

    a = stored_signals(json.loads(json.dumps(t)))  # the stored record as arrays
    assert a["frames"].tolist() == list(range(10))
    assert a["flagged"].tolist() == [f in (3, 8) for f in range(10)]
    assert np.array_equal(a["search_error"], a["error"]) and not a["stage_move"].any()
    assert a["over_bound"][6] > 4 > a["over_bound"][5] and np.isnan(a["sigma"]).all()
    assert a["score"].tolist() == [0.9] * 10 and a["stage"] == [None] * 10
    json.dumps(out, allow_nan=False)
    stored = json.loads(json.dumps(out))
    again = json.loads(json.dumps(out))
    assert regoal(again) == ["goals"] and again == stored  # the goals as run() stored them
