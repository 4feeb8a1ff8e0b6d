"""The acceptance study's ``--final likelihood`` (the likelihood final stage in the tracking options,
``TrackingOptions.refine_likelihood``), ``--final-highpass`` and ``--glare``; the default the runs as
before (no stage)."""

import numpy as np
import pytest

from core.studies.tracking import acceptance


def test_main_hands_the_stage_options_to_the_run(monkeypatch):
    import core.io.atomic

    calls = []
    monkeypatch.setattr(acceptance, "run", lambda **kw: calls.append(kw) or {})
    monkeypatch.setattr(core.io.atomic, "print_json", lambda *a, **k: None)
    acceptance.main(["--quick"])
    acceptance.main(["--quick", "--final", "likelihood"])
    acceptance.main(["--quick", "--final", "likelihood", "--final-highpass", "2", "--glare"])
    assert [(c["final"], c["final_highpass_px"], c["glare"]) for c in calls] == [
        (None, None, False), ("likelihood", None, False), ("likelihood", 2.0, True)]
    with pytest.raises(SystemExit):  # a high-pass without the stage
        acceptance.main(["--quick", "--final-highpass", "2"])
    with pytest.raises(SystemExit):
        acceptance.main(["--quick", "--final", "gc"])


def test_study_options_with_the_stage_and_without():
    from core.tracking.trial import TrackingOptions

    for mode in ("joint", "sequential"):  # the default: the options as before
        assert acceptance.study_options(mode) == acceptance.study_options(mode, final="none")
    assert acceptance.study_options("joint") == TrackingOptions(mode="joint")
    o = acceptance.study_options("joint", final="likelihood")
    assert o.refine_likelihood and o.registration.final == "likelihood"
    assert o.registration.final_highpass_px == TrackingOptions().registration.final_highpass_px == 4.0
    assert o.registration.search == "newton"
    o = acceptance.study_options("sequential", "local", final="likelihood", final_highpass_px=2)
    assert o.registration.final_highpass_px == 2.0 and o.registration.search == "local"
    assert o.sequential_subtract is True
    with pytest.raises(ValueError, match="final"):
        acceptance.study_options("joint", final="gc")
    with pytest.raises(ValueError, match="final_highpass_px"):
        acceptance.study_options("joint", final_highpass_px=2.0)


def test_the_stage_reaches_the_tracking_and_is_recorded(monkeypatch):
    """A ten-frame 64² trial of the talus (the low-pass needs ten): the config records the stage,
    and the stage moves the tracked poses (the errors differ from the run without it, which
    records none); each frame's signals record it (:func:`_signals_hold`)."""
    monkeypatch.setattr(acceptance, "cramer_rao", lambda ts, frames: {})  # not what is tested here
    ts = acceptance.TrackingScene(n_frames=10, pixels=64, spacing=2.0, device="cpu", names=("talus",),
                                  phase=(0.0, 0.06))
    plain = acceptance.run(ts=ts, capture_trials=0)
    staged = acceptance.run(ts=ts, capture_trials=0, final="likelihood", final_highpass_px=1.0)
    assert plain["config"]["final"] == "none" and plain["config"]["final_highpass_px"] is None
    assert "final_model" not in plain["config"] and plain["config"]["glare_undone"] is False
    cfg = staged["config"]
    assert cfg["final"] == "likelihood" and cfg["final_highpass_px"] == 1.0 and "final_model" in cfg
    a = np.array(plain["tracking"]["talus"]["per_frame_error"])
    b = np.array(staged["tracking"]["talus"]["per_frame_error"])
    assert a.shape == b.shape == (10, 6) and np.all(np.isfinite(b))
    assert np.max(np.abs(a - b)) > 1e-4  # some frame's pose moved by the stage
    _signals_hold(staged, ts)
    assert plain["tracking"]["talus"]["per_frame_signals"]["stage"] == [None] * 10


def _signals_hold(out: dict, ts) -> None:
    """A real run's per-frame signals with the final stage: every frame with a pose has its score, work,
    the stage's outcome; where the stage's pose was taken, its move's vector has the size its timing
    gives, and the pose is the searched pose moved by it; the stored record read back as arrays
    (stored_signals) agrees, and the result regoals."""
    import json

    from core.geometry.transforms import pose_from_params
    from core.studies.tracking.acceptance_goals import regoal
    from core.studies.tracking.acceptance_records import stored_signals

    t = out["tracking"]["talus"]
    sig, fwp = t["per_frame_signals"], t["frames_with_pose"]
    assert fwp and all(len(v) == len(fwp) for v in sig.values())
    assert all(s is not None for s in sig["score"]) and min(sig["evaluations"]) > 0
    assert set(sig["stage"]) <= {"taken", "rejected", "untaken", None} and "taken" in sig["stage"]
    c = ts.models[0].centroid
    for k, f in enumerate(fwp):
        if sig["stage"][k] != "taken":
            assert sig["stage_move"][k] is None and sig["search_error"][k] is None
            continue
        m = np.asarray(sig["stage_move"][k])
        assert np.linalg.norm(m[:3]) == pytest.approx(sig["stage_move_mm"][k], abs=2e-5)
        assert np.linalg.norm(m[3:]) == pytest.approx(sig["stage_move_deg"][k], abs=2e-5)
        se = np.asarray(sig["search_error"][k])
        S = pose_from_params(np.r_[se[:3], np.radians(se[3:])], center=c, base=ts.truth(f)[0])
        P = pose_from_params(np.r_[m[:3], np.radians(m[3:])], center=c, base=S)
        assert np.allclose(acceptance.pose_errors(P, ts.truth(f)[0], c), t["per_frame_error"][k], atol=1e-4)
    a = stored_signals(json.loads(json.dumps(t)))
    for k, st in enumerate(sig["stage"]):
        assert np.allclose(a["search_error"][k], sig["search_error"][k] if st == "taken" else a["error"][k])
    json.dumps(out, allow_nan=False)
    regoal(json.loads(json.dumps(out)))


def test_the_figures_title_names_the_stage_only_when_run():
    from core.studies.tracking.acceptance_figure import _stage

    assert _stage({}) == _stage({"final": "none"}) == ""  # results of before the option, the default
    assert _stage({"final": "likelihood", "final_highpass_px": 4.0}) == ", final stage: likelihood at 4.0 px"
