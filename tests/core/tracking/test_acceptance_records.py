"""The acceptance study's per-bone records (core.studies.tracking.acceptance_records): each flagged
frame's reasons (its flags, then its notes), the frames over 4x the Cramér–Rao bound, the frames not
converged; the goals' lists of them, flagged or not and why (core.studies.tracking.acceptance_goals:
over_4x_frames, flagged_within_4x, unconverged_frames)."""

from types import SimpleNamespace

import numpy as np

from core.studies.tracking.acceptance_goals import over_4x_frames, regoal
from core.studies.tracking.acceptance_records import NOTE, flag_reasons, over_bound, reasons
from core.tracking.flags_post import FLAG


def _res(flags: dict, notes: dict | None = None, name: str = "talus"):
    notes = notes or {}
    return SimpleNamespace(results={(name, f): SimpleNamespace(flags=tuple(v), notes=tuple(notes.get(f, ())))
                                    for f, v in flags.items()})


def test_flag_reasons_are_the_flagged_frames_flags_then_notes():
    res = _res({0: [], 3: ["score drop", "uncertain"], 11: [f"{FLAG} (2.1x)"], 2: []},
               notes={0: ["start corrected by restarts"], 11: ["contact: 0.20 mm resolved to 0.00 mm"]})
    res.results[("tibia", 5)] = SimpleNamespace(flags=("other bone",), notes=())
    out = flag_reasons(res, "talus")
    assert out == {"3": ["score drop", "uncertain"],
                   "11": [f"{FLAG} (2.1x)", NOTE + "contact: 0.20 mm resolved to 0.00 mm"]}
    assert list(out) == ["3", "11"]  # ascending frames, JSON keys; unflagged frame 0's note left out
    assert flag_reasons(res, "calcaneus") == {}
    assert reasons(SimpleNamespace(flags=())) == []  # a result without notes


def test_over_bound_counts_silent_and_false_flags():
    bound = {"rms_mm": 0.01, "rms_deg": 0.1}
    E = np.zeros((5, 6))
    E[1, :3] = [0.05, 0.0, 0.0]      # 5x in translation, flagged
    E[2, 3:] = [0.0, 0.0, -0.45]     # 4.5x in rotation, not flagged: silent
    E[3, :3] = [0.02, 0.02, 0.02]    # 3.5x: not over
    frames = [0, 1, 2, 3, 5]         # frame 4 had no pose
    res = _res({0: [], 1: ["score drop"], 2: [], 3: ["uncertain"], 5: []})
    out = over_bound(res, "talus", E, frames, bound)
    assert out["frames"] == [1, 2]
    assert out["silent"] == 1 and out["silent_frames"] == [2]
    assert out["false_flags"] == 1 and out["false_flag_frames"] == [3]



def _stored(**talus) -> dict:
    """A stored one-mode acceptance result of one bone (talus, bound 0.01 mm / 0.1°): frames 3
    (flagged) and 6 (silent) over 4x, frame 8 flagged though good; ``talus`` overrides its record."""
    t = {"converged_fraction": 1.0, "within_2_sigma_fraction": None,
         "rms_over_bound": {"mm": 2.0, "deg": 1.0}, "flagged_frames": [3, 8],
         "flag_reasons": {"3": ["score drop", NOTE + "start corrected by restarts"], "8": [f"{FLAG} (1.2x)"]},
         "over_4x_bound": {"k": 4.0, "frames": [3, 6], "silent": 1, "silent_frames": [6], "false_flags": 1,
                           "silent_details": [{"frame": 6, "notes": ["unchecked (its neighbours flagged)"]}]}}
    t.update(talus)
    return {"study": "core.studies.tracking.acceptance", "config": {"mode": "joint"},
            "tracking": {"talus": t}}


def test_the_goals_list_each_frame_over_4x_flagged_or_not_and_why():
    d = _stored()
    assert regoal(d) == ["goals"]
    g = d["goals"]["talus"]
    assert g["silent_over_4x"] == [1, False]
    assert g["over_4x_frames"] == [
        {"frame": 3, "flagged": True, "reasons": ["score drop", NOTE + "start corrected by restarts"]},
        {"frame": 6, "flagged": False, "reasons": [NOTE + "unchecked (its neighbours flagged)"]}]
    none_over = _stored(over_4x_bound={"frames": [], "silent_frames": []})["tracking"]["talus"]
    assert over_4x_frames(none_over) == []


def test_the_goals_list_the_frames_not_converged_and_the_flagged_ones_within_4x_with_why():
    """``converged 98 %`` traced to its frames: ``unconverged_frames`` with their reasons where the record
    lists them (none in a result stored before them: ``--regoal`` leaves the list out); the flagged frames
    within 4x the bound with theirs, from the stored flagged frames (old results too)."""
    d = _stored(converged_fraction=0.9, unconverged_frames=[3, 4])
    regoal(d)
    g = d["goals"]["talus"]
    assert g["converged_fraction"] == [0.9, False]
    assert g["unconverged_frames"] == [
        {"frame": 3, "reasons": ["score drop", NOTE + "start corrected by restarts"]},
        {"frame": 4, "reasons": []}]  # not flagged (e.g. no pose: nothing returned why)
    assert g["flagged_within_4x"] == [{"frame": 8, "reasons": [f"{FLAG} (1.2x)"]}]
    old = _stored()  # no unconverged_frames
    regoal(old)
    assert "unconverged_frames" not in old["goals"]["talus"]
    assert old["goals"]["talus"]["flagged_within_4x"] == g["flagged_within_4x"]
    # a flagged frame without a pose (not in frames_with_pose) is neither over nor within 4x
    posed = _stored(frames_with_pose=[0, 1, 2, 3, 4, 5, 6, 7])
    regoal(posed)
    assert posed["goals"]["talus"]["flagged_within_4x"] == []


def test_the_records_list_the_frames_not_converged():
    from dataclasses import replace

    from core.studies.tracking.acceptance_records import bone_records

    ts, res = _scene_and_result(4, flagged=(1,))
    res.results[("talus", 1)] = replace(res.results[("talus", 1)], converged=False)
    res.results[("talus", 3)] = replace(res.results[("talus", 3)], pose=None, converged=False)
    t = bone_records(ts, res, 278.0).tracking["talus"]
    assert t["converged_fraction"] == 0.5 and t["unconverged_frames"] == [1, 3]


def test_a_result_stored_before_the_reasons_regoals_without_them():
    """No ``flag_reasons`` (a run before them): no ``over_4x_frames``, the other goals as before; no
    ``silent_details`` (older still): the silent frame has no ``reasons``; no bound: no list."""
    old = _stored()
    del old["tracking"]["talus"]["flag_reasons"]
    new = _stored()
    regoal(old)
    regoal(new)
    assert "over_4x_frames" not in old["goals"]["talus"] and "flagged_within_4x" not in old["goals"]["talus"]
    assert old["goals"]["talus"] == {k: v for k, v in new["goals"]["talus"].items()
                                     if k not in ("over_4x_frames", "flagged_within_4x")}
    older = _stored()
    del older["tracking"]["talus"]["over_4x_bound"]["silent_details"]
    regoal(older)
    assert older["goals"]["talus"]["over_4x_frames"][1] == {"frame": 6, "flagged": False}
    t = _stored()["tracking"]["talus"]
    del t["over_4x_bound"]
    assert over_4x_frames(t) is None


def _scene_and_result(n_frames: int, flagged=()):
    """A stand-in scene of one bone (talus) whose truth moves 1 mm a frame along x, and its tracking
    result 0.01 mm off the truth in every frame, ``flagged`` frames flagged."""
    from core.tracking.results import FrameResult, TrackingResult

    def truth(f):
        T = np.eye(4)
        T[0, 3] = float(f)
        return T[None]

    ts = SimpleNamespace(scene=SimpleNamespace(n_frames=n_frames), names=("talus",),
                         models=[SimpleNamespace(centroid=np.zeros(3))], truth=truth)
    res = {}
    for f in range(n_frames):
        P = truth(f)[0].copy()
        P[1, 3] += 0.01
        res[("talus", f)] = FrameResult("talus", f, P, 0.9, 1, 0.0, True,
                                        flags=("score drop",) if f in flagged else ())
    return ts, TrackingResult(("talus",), tuple(range(n_frames)), res, "complete", 0.0)


def test_a_trial_too_short_for_the_low_pass_keeps_its_records():
    """Under FILTER_MIN_FRAMES frames (the Butterworth filter's least) the bone has no filtered
    errors instead of the run failing after tracking; from that many on it has them."""
    from core.studies.tracking.acceptance_records import FILTER_MIN_FRAMES, bone_records

    ts, res = _scene_and_result(3, flagged=(1,))
    rec = bone_records(ts, res, 278.0)
    t = rec.tracking["talus"]
    assert t["filtered"] == {"cutoff_hz": None, "rms_error_mm": None, "rms_error_deg": None,
                             "max_error_mm": None, "max_error_deg": None, "frames": 0}
    assert abs(t["rms_error_mm"] - 0.01) < 1e-9 and rec.frames["talus"] == [0, 1, 2]
    assert t["flag_reasons"] == {"1": ["score drop"]}
    ts, res = _scene_and_result(FILTER_MIN_FRAMES)
    t = bone_records(ts, res, 278.0).tracking["talus"]
    assert t["filtered"]["frames"] == FILTER_MIN_FRAMES and t["filtered"]["cutoff_hz"] is not None


def test_every_stored_acceptance_result_regoals():
    """Every stored acceptance result (resources/benchmarks/tracking_acceptance*.json) regoals without an
    error, with ``over_4x_frames`` only where its records keep the reasons; the first ones, without
    ``over_4x_bound``, without ``silent_over_4x``."""
    import json
    from pathlib import Path

    bench = Path(__file__).resolve().parents[3] / "resources" / "benchmarks"
    files = sorted(bench.glob("tracking_acceptance*.json"))
    assert files
    for p in files:
        d = json.loads(p.read_text(encoding="utf-8"))
        regoal(d)
        runs = [r for r in (d.get("runs") or {"mode": d}).values() if "goals" in r]
        assert runs, p.name
        for r in runs:
            for n, g in r["goals"].items():
                # only results stored with the reasons (flag_reasons, since 3ee57ee) list them
                assert ("over_4x_frames" in g) == ("flag_reasons" in r["tracking"][n]), p.name
                assert ("flagged_within_4x" in g) == ("over_4x_frames" in g), p.name
                assert ("unconverged_frames" in g) == ("unconverged_frames" in r["tracking"][n]), p.name
                assert ("silent_over_4x" in g) == ("over_4x_bound" in r["tracking"][n]), p.name


def test_the_records_keep_every_frames_signals_the_stage_and_the_searched_pose():
    """``per_frame_signals`` (frame_signals), in frames_with_pose's order, flagged or not: frame 0 without
    a stage, frame 1's stage taken (moved 0.02 mm in y from the searched pose, which is 0.01 mm off the
    truth in x), frame 2's rejected (its pose the search's, the move's size kept), frame 3's run but not
    taken; frame 4 has no pose (left out)."""
    from dataclasses import replace

    from core.studies.tracking.acceptance_records import bone_records, frame_signals

    ts, res = _scene_and_result(5, flagged=(2,))
    R = res.results
    search = ts.truth(1)[0].copy()
    search[0, 3] += 0.01
    stage = search.copy()
    stage[1, 3] += 0.02
    R[("talus", 1)] = replace(R[("talus", 1)], pose=stage, search_pose=search, retried=True,
                              confidence={"sigma": [0.01] * 6, "cost_noise": 0.25},
                              timing={"likelihood_taken": 1, "likelihood_move_mm": 0.02,
                                      "likelihood_move_deg": 0.0, "likelihood_s": 0.12345,
                                      "likelihood_steps": 3})
    R[("talus", 2)] = replace(R[("talus", 2)], search_pose=R[("talus", 2)].pose,
                              timing={"likelihood_taken": 0, "likelihood_rejected": 1,
                                      "likelihood_move_mm": 0.3, "likelihood_move_deg": float("nan")})
    R[("talus", 3)] = replace(R[("talus", 3)], timing={"likelihood_taken": 0, "likelihood_s": 0.01})
    R[("talus", 4)] = replace(R[("talus", 4)], pose=None, score=float("nan"), converged=False)
    rec = bone_records(ts, res, 278.0)
    s = rec.tracking["talus"]["per_frame_signals"]
    assert rec.frames["talus"] == [0, 1, 2, 3]  # (frames_with_pose)
    assert all(len(v) == 4 for v in s.values())
    assert s["stage"] == [None, "taken", "rejected", "untaken"]
    assert s["stage_move_mm"] == [None, 0.02, 0.3, None] and s["stage_move_deg"] == [None, 0.0, None, None]
    assert s["stage_s"] == [None, 0.1235, None, 0.01] and s["stage_steps"] == [None, 3, None, None]
    assert s["stage_move"][0] is None and s["stage_move"][2:] == [None, None]
    assert np.allclose(s["stage_move"][1], [0, 0.02, 0, 0, 0, 0], atol=1e-9)
    assert np.allclose(s["search_error"][1], [0.01, 0, 0, 0, 0, 0], atol=1e-9)
    assert [s["search_error"][f] for f in (0, 2, 3)] == [None] * 3  # the pose is the search's
    assert s["score"] == [0.9] * 4 and s["evaluations"] == [1] * 4 and s["time_s"] == [0.0] * 4
    assert s["retried"] == [False, True, False, False] and s["cost_noise"] == [None, 0.25, None, None]
    assert frame_signals(res, "talus", [], ts.truth, np.zeros(3)) == {k: [] for k in s}
    import json

    from core.studies.tracking.acceptance_records import add_bound, stored_signals

    json.dumps(s, allow_nan=False)
    add_bound(rec, ts, res, {})  # (no bound: per_frame_error and frames_with_pose only)
    t = json.loads(json.dumps(rec.tracking["talus"]))
    a = stored_signals(t)
    assert np.allclose(a["search_error"][1], s["search_error"][1]) and np.array_equal(a["search_error"][0],
                                                                                    a["error"][0])
    assert np.allclose(a["stage_move"][1], s["stage_move"][1]) and not a["stage_move"][[0, 2, 3]].any()
    assert a["flagged"].tolist() == [False, False, True, False] and np.isnan(a["over_bound"]).all()
    assert a["stage_s"][1] == 0.1235 and np.isnan(a["stage_s"][0]) and a["retried"].tolist() == [0, 1, 0, 0]
    assert a["sigma"][1].tolist() == [0.01] * 6 and np.isnan(a["sigma"][0]).all()
    del t["per_frame_signals"]
    assert stored_signals(t) is None  # a run before them


def test_a_frame_result_keeps_the_searched_pose_its_final_stage_started_from():
    """frame_result: ``search_pose`` is the stage fit's similarity pose (taken, or rejected: the pose
    itself), None where the result has no stage fit; not in to_dict (a journal keeps the pose only)."""
    from core.tracking.attempt import Attempt
    from core.tracking.frame_records import Work, frame_result

    S, P = np.eye(4), np.eye(4)
    P[0, 3] = 0.05
    fit = SimpleNamespace(similarity=SimpleNamespace(pose=S))
    staged = SimpleNamespace(pose=P, score=0.8, timing={}, fit=fit)
    plain = SimpleNamespace(pose=P, score=0.8, timing={}, fit=None)
    a = Attempt(staged, [], False, 0, 0.0, None, None)
    fr = frame_result("talus", 1, a, Work())
    assert np.array_equal(fr.search_pose, S) and np.array_equal(fr.pose, P)
    assert "search_pose" not in fr.to_dict()
    a.result = plain
    assert frame_result("talus", 1, a, Work()).search_pose is None
