"""The acceptance study's goal table, flag counts, joint space and both modes on one scene
(core.studies.tracking.acceptance_goals, acceptance.main --mode joint,sequential), and the frames
made in worker processes (core.studies.tracking.trial_frames)."""

from types import SimpleNamespace

import numpy as np
import pytest

from core.studies.tracking import acceptance
from core.studies.tracking.acceptance_goals import compare_modes, flag_counts, goals, joint_space


def _bone(mm, deg, conv=1.0, silent=0, inside=0.95):
    return {"rms_error_mm": mm, "rms_error_deg": deg, "converged_fraction": conv,
            "rms_over_bound": {"mm": mm / 0.01, "deg": deg / 0.1}, "over_4x_bound": {"silent": silent},
            "within_2_sigma_fraction": inside}


def test_goals_say_per_bone_what_is_met():
    g = goals({"talus": _bone(0.012, 0.13, conv=0.98, silent=1, inside=0.85),
               "tibia": _bone(0.0125, 0.1, inside=None)})
    t = g["talus"]
    assert t["rms_over_bound_mm"] == [pytest.approx(1.2), True]
    assert t["rms_over_bound_deg"] == [pytest.approx(1.3), False]
    assert t["converged_fraction"] == [0.98, False] and t["silent_over_4x"] == [1, False]
    assert t["within_2_sigma"] == [0.85, False]
    assert g["tibia"]["rms_over_bound_mm"][1] and g["tibia"]["silent_over_4x"] == [0, True]
    assert g["tibia"]["within_2_sigma"] == [None, False]


def test_compare_modes_needs_both_and_gives_joint_over_sequential():
    runs = {"joint": {"tracking": {"talus": {"rms_error_mm": 0.02, "rms_error_deg": 0.3}}}}
    assert compare_modes(runs) == {}
    runs["sequential"] = {"tracking": {"talus": {"rms_error_mm": 0.04, "rms_error_deg": 0.2}}}
    c = compare_modes(runs)["talus"]
    assert c["mm"] == {"joint": 0.02, "sequential": 0.04, "ratio": 0.5}
    assert c["deg"]["ratio"] == pytest.approx(1.5)


def test_flag_counts_are_the_returned_flags_with_the_trajectory_pass_apart():
    from core.tracking.flags_post import FLAG

    flags = {0: (), 1: ("score drop",), 2: (f"{FLAG}: 0.05 mm",), 3: ("jump", f"{FLAG}: 0.3 deg")}
    res = SimpleNamespace(results={("talus", f): SimpleNamespace(flags=v) for f, v in flags.items()}
                          | {("tibia", 0): SimpleNamespace(flags=("lost",))})
    out = flag_counts(res, "talus")
    assert out == {"flagged_frames": [1, 2, 3], "flagged_off_trajectory_only": [2]}


@pytest.fixture(scope="module")
def scene():
    return acceptance.TrackingScene(n_frames=3, pixels=64, spacing=2.0, device="cpu")


def test_joint_space_of_the_true_poses_is_the_truths(scene):
    res = SimpleNamespace(results={(n, f): SimpleNamespace(pose=scene.truth(f)[b])
                                   for b, n in enumerate(scene.names) for f in range(3)})
    res.results[("talus", 1)] = SimpleNamespace(pose=None)
    js = joint_space(scene, res)
    assert set(js) == {"tibia-talus", "talus-calcaneus"}
    for v in js.values():
        assert v["rms_diff_mm"] == 0.0 and v["max_abs_diff_mm"] == 0.0
        assert np.isfinite(v["truth_min_mm"]) and v["truth_min_mm"] < 10.0
        assert v["min_frame"] != 1
    shifted = dict(res.results)
    for f in (0, 2):  # the talus moved 1 mm away from the tibia's centroid: the joint space changes
        T = scene.truth(f)
        c = [T[b][:3, :3] @ scene.models[b].centroid + T[b][:3, 3] for b in (0, 1)]
        P = T[1].copy()
        P[:3, 3] += (c[1] - c[0]) / np.linalg.norm(c[1] - c[0])
        shifted[("talus", f)] = SimpleNamespace(pose=P)
    js2 = joint_space(scene, SimpleNamespace(results=shifted))
    # by ~0.12 mm on the exact surfaces: their nearest points are the malleolus beside the talus
    # (contact normal along lab y), which a move along the long axis changes little
    assert js2["tibia-talus"]["max_abs_diff_mm"] > 0.1


def test_joint_space_is_measured_on_the_exact_surfaces(scene):
    """The joint space is the phantoms' exact surface distance whatever the models' voxels: the
    tibia moved along the contact normal by +-0.3 mm opens or closes it by 0.3 mm (into the talus:
    negative allowed), where the voxel-mask measure at this scene's 2 mm voxels reads mm low."""
    from core.synthetic.motion import _pair, _spaces

    T = np.stack([scene.truth(f) for f in range(3)])
    res = SimpleNamespace(results={(n, f): SimpleNamespace(pose=T[f, b])
                                   for b, n in enumerate(scene.names) for f in range(3)})
    exact, n = _spaces(_pair("tibia", "talus"), T[:, 0], T[:, 1])
    js = joint_space(scene, res)["tibia-talus"]
    k = int(np.argmin(exact))
    assert js["surfaces"] == "exact" and js["truth_min_frame"] == k
    assert js["truth_min_mm"] == pytest.approx(exact[k], abs=1e-12) and 0.3 < js["truth_min_mm"] < 0.7
    mask = joint_space(scene, res, surfaces="mask")["tibia-talus"]
    assert mask["truth_min_mm"] < js["truth_min_mm"] - 1.0  # the old measure, 2 mm shell voxels
    for delta in (0.3, -0.6):
        moved = dict(res.results)
        for f in range(3):
            P = T[f, 0].copy()
            P[:3, 3] += delta * n[f]
            moved[("tibia", f)] = SimpleNamespace(pose=P)
        got = joint_space(scene, SimpleNamespace(results=moved))["tibia-talus"]
        assert got["min_frame"] == k
        assert got["min_mm"] - js["truth_min_mm"] == pytest.approx(delta, abs=0.03)
    with pytest.raises(ValueError, match="surfaces"):
        joint_space(scene, res, surfaces="mesh")


_IN_WORKERS = """
import numpy as np
from core.studies.tracking import acceptance
from core.studies.tracking.trial_frames import synthesise
ts = acceptance.TrackingScene(n_frames=2, pixels=64, spacing=2.0, device="cpu", names=("talus",))
here = [np.array(x) for x in ts.frames(1)]
ts._cache.clear()
synthesise(ts, range(2), workers=2)
assert sorted(ts._cache) == [0, 1]
for a, b in zip(here, ts._cache[1], strict=True):
    assert np.array_equal(a, b)
print("same frames")
"""


def test_frames_made_in_workers_are_the_frames_made_here(tmp_path):
    # in a fresh process: the workers are forked, and a fork of this test process (other tests'
    # threads — a Dask cluster's, OpenCV's — may hold locks at that moment) can hang in OpenCV
    import os
    import subprocess
    import sys

    # Warp's kernel cache is the run's (tests/conftest.py): compiling every kernel again in the
    # child took most of this test's time
    env = {**os.environ, "XDG_CACHE_HOME": str(tmp_path)}
    out = subprocess.run([sys.executable, "-c", _IN_WORKERS], capture_output=True, text=True, timeout=600,
                         env=env, cwd=os.path.dirname(os.path.dirname(os.path.dirname(os.path.dirname(
                             os.path.abspath(__file__))))))
    assert out.returncode == 0 and "same frames" in out.stdout, out.stderr[-2000:]


def test_main_runs_both_modes_on_one_scene(monkeypatch, tmp_path):
    import json

    import core.io.atomic

    calls = []
    monkeypatch.setattr(acceptance, "tracking_scene", lambda **kw: "scene")
    monkeypatch.setattr(acceptance, "run", lambda **kw: calls.append(kw) or {"tracking": {}})
    monkeypatch.setattr(core.io.atomic, "print_json", lambda obj, out=None: out and
                        (tmp_path / "o.json").write_text(json.dumps(obj)))
    acceptance.main(["--quick", "--mode", "joint,sequential", "--figure", "f.png", "--workers", "4",
                     "--machine-name", "this 2-core x86_64 machine", "--out", str(tmp_path / "o.json")])
    assert [c["mode"] for c in calls] == ["joint", "sequential"]
    assert [c["ts"] for c in calls] == ["scene", "scene"] and calls[0]["workers"] == 4
    assert calls[0]["capture_trials"] is None and calls[1]["capture_trials"] == 0
    assert [c["figure"] for c in calls] == ["f_joint.png", "f_sequential.png"]
    out = json.loads((tmp_path / "o.json").read_text())
    assert list(out["runs"]) == ["joint", "sequential"] and out["joint_vs_sequential"] == {}
    assert out["machine_name"] == "this 2-core x86_64 machine"  # --machine-name, as the other studies
    acceptance.main(["--quick", "--machine-name", "one NVIDIA H100", "--out", str(tmp_path / "o.json")])
    out = json.loads((tmp_path / "o.json").read_text())
    assert calls[-1]["mode"] == "joint" and out == {"tracking": {}, "machine_name": "one NVIDIA H100"}
    with pytest.raises(SystemExit):
        acceptance.main(["--mode", "joint,both"])


def test_mode_figures_are_named_before_the_extension_only():
    from core.studies.tracking.acceptance import _mode_path

    assert _mode_path("out/errors.png", "joint") == "out/errors_joint.png"
    assert _mode_path("runs.v2/errors", "sequential") == "runs.v2/errors_sequential"
    assert _mode_path("runs.v2/errors.png", "joint") == "runs.v2/errors_joint.png"


def test_joint_space_of_a_bone_never_tracked_is_none_not_a_crash(scene):
    """A bone lost in every frame: its pairs say so (the study's other results are kept)."""
    res = SimpleNamespace(results={(n, f): SimpleNamespace(pose=None if n == "talus" else scene.truth(f)[b])
                                   for b, n in enumerate(scene.names) for f in range(3)})
    js = joint_space(scene, res)
    for v in js.values():
        assert v["min_mm"] is None and v["min_frame"] is None and v["rms_diff_mm"] is None
        assert v["max_abs_diff_mm"] is None and np.isfinite(v["truth_min_mm"])


def test_the_figures_legends_cover_no_curve(tmp_path, monkeypatch):
    """Errors largest at the trial's end, where the legends sit: each legend lies above every curve."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    kept = []
    monkeypatch.setattr(plt, "close", lambda fig=None: kept.append(fig))
    fr = list(range(20))
    ramp = np.linspace(0.01, 1.0, 20)[:, None] * np.array([0.1, 0.05, 0.02, 0.3, 0.2, 0.4])
    errs = {n: (fr, ramp * (1 + 0.2 * k)) for k, n in enumerate(("tibia", "talus", "calcaneus"))}
    cfg = {"pixels": 64, "voxel_mm": 2.0, "mode": "joint", "search": "newton", "correction": "grid",
           "frame_rate_hz": 278.0}
    acceptance._figure(errs, errs, str(tmp_path / "f.png"), cfg, flagged={"talus": [19]})
    (fig,) = kept
    fig.canvas.draw()
    for a in fig.axes:
        box = a.get_legend().get_window_extent().transformed(a.transData.inverted())
        for line in a.get_lines():
            x, y = (np.asarray(v, float) for v in line.get_data())
            under = (x >= box.x0) & (x <= box.x1) & (y > box.y0)
            if len(x) > 2:  # the curves (the bound's and target's lines span the axis)
                assert not under.any(), (a.get_ylabel(), line.get_label())


def test_the_study_tracks_sequentially_as_talus_track_does_on_its_flatfield_corrected_frames(monkeypatch):
    """Sequential mode subtracts the other bones in the search by default, as track_study's auto
    does for flatfield-corrected frames; on/off as given; joint options untouched."""
    from core.tracking.trial import TrackingOptions

    assert acceptance.study_options("sequential").sequential_subtract is True
    assert acceptance.study_options("sequential", sequential_subtract=False).sequential_subtract is False
    assert acceptance.study_options("joint") == TrackingOptions(mode="joint")
    assert acceptance.study_options("sequential", "local").registration.search == "local"
    calls = []
    monkeypatch.setattr(acceptance, "run", lambda **kw: calls.append(kw) or {})
    monkeypatch.setattr(acceptance, "tracking_scene", lambda **kw: "scene")
    import core.io.atomic

    monkeypatch.setattr(core.io.atomic, "print_json", lambda obj, out=None: None)
    acceptance.main(["--quick", "--mode", "sequential"])
    acceptance.main(["--quick", "--mode", "sequential", "--sequential-subtract", "off"])
    assert [c["sequential_subtract"] for c in calls] == [None, False]


@pytest.mark.parametrize("talus", ["flagged", "no pose"])
def test_a_bone_flagged_or_without_a_pose_in_every_frame_keeps_the_runs_results(tmp_path, monkeypatch, talus):
    """run() to its JSON and figure when the filter has no frame of a bone (all flagged: NaN for the
    low-pass) or the bone has no pose at all (its per-frame errors empty: IndexError before): its
    filtered (and for no pose its per-frame) errors are None, the others' as usual (the tracker
    replaced by the true poses, 0.01 mm off; 64² views, 12 frames)."""
    import json

    import core.tracking.trial as trial_mod
    from core.tracking.results import FrameResult, TrackingResult

    ts = acceptance.TrackingScene(n_frames=12, pixels=64, spacing=2.0, device="cpu")

    def track(renderer, models, frames, order, keyframes=None, options=None):
        res = {}
        for f in order:
            for b, n in enumerate(ts.names):
                P = ts.truth(f)[b].copy()
                P[0, 3] += 0.01
                if n == "talus" and talus == "no pose":
                    P = None
                res[(n, f)] = FrameResult(n, f, P, 0.9, 1, 0.0, P is not None,
                                          flags=("test",) if n == "talus" else ())
        return TrackingResult(tuple(ts.names), tuple(order), res, "complete", 0.0)

    monkeypatch.setattr(trial_mod, "track", track)
    out = acceptance.run(ts=ts, mode="joint", capture_trials=0, figure=str(tmp_path / "f.png"))
    t = out["tracking"]["talus"]
    assert t["filtered"]["rms_error_mm"] is None and t["filtered"]["frames"] == 0
    # the frames behind the converged fraction, with why (no pose: not converged, nothing returned why)
    assert t["unconverged_frames"] == ([] if talus == "flagged" else list(range(12)))
    assert out["goals"]["talus"]["unconverged_frames"] == [{"frame": f, "reasons": ["test"]}
                                                           for f in t["unconverged_frames"]]
    assert out["tracking"]["tibia"]["unconverged_frames"] == [] == out["goals"]["tibia"]["unconverged_frames"]
    assert t["rms_over_bound"]["filtered_deg"] is None
    if talus == "no pose":
        assert t["rms_error_mm"] is t["max_error_deg"] is t["mean_error"] is t["std_error"] is None
        assert t["rms_over_bound"]["mm"] is None and t["per_frame_error"] == []
        assert t["over_4x_bound"]["frames"] == []
        assert out["goals"]["talus"]["rms_over_bound_mm"] == [None, False]
        one = {"tracking": {"talus": t}}
        assert compare_modes({"joint": one, "sequential": one})["talus"]["mm"]["ratio"] is None
    else:
        assert t["rms_error_mm"] == pytest.approx(0.01, abs=1e-6)
    assert np.isfinite(out["tracking"]["tibia"]["filtered"]["rms_error_mm"])
    assert out["tracking"]["tibia"]["rms_error_mm"] == pytest.approx(0.01, abs=1e-6)
    json.dumps(out, allow_nan=False)  # the run's JSON: no NaN for a bone without frames
    assert (tmp_path / "f.png").stat().st_size > 0


# joint against sequential on the paired per-frame errors, the σ coverage per axis, --regoal

def _run(E, sigma=None, bound=(0.04, 0.16), frames=None):
    """An acceptance run of one bone (talus) with per-frame errors ``E`` ((n, 6): mm, degrees)."""
    E = np.asarray(E, dtype=float)
    et, er = np.linalg.norm(E[:, :3], axis=1), np.linalg.norm(E[:, 3:], axis=1)
    t = {"rms_error_mm": float(np.sqrt(np.mean(et ** 2))), "rms_error_deg": float(np.sqrt(np.mean(er ** 2))),
         "cramer_rao": {"rms_mm": bound[0], "rms_deg": bound[1]}, "per_frame_error": E.tolist()}
    if sigma is not None:
        t["per_frame_sigma"] = sigma
    if frames is not None:
        t["frames_with_pose"] = frames
    return {"config": {"frames": len(E) if frames is None else 1 + max(frames)}, "tracking": {"talus": t}}


def _errors(n=60, seed=0, scale=(0.03, 0.2)):
    g = np.random.default_rng(seed)
    return np.column_stack([g.normal(0, scale[0], (n, 3)), g.normal(0, scale[1], (n, 3))])


def test_equal_modes_are_at_least_as_good_on_the_paired_errors():
    E = _errors()
    c = compare_modes({"joint": _run(E), "sequential": _run(E)})["talus"]
    assert c["decided_on"] == "paired" and c["at_least_as_good"]
    for u, m in (("mm", 0.125 * 0.04), ("deg", 0.125 * 0.16)):
        p = c[u]["paired"]
        assert p["interval95"] == [0.0, 0.0] and p["verdict"] == "not resolved"
        assert p["margin"] == pytest.approx(m) and c[u]["ratio"] == pytest.approx(1.0)


def test_joint_clearly_worse_is_not_met():
    E = _errors()
    J = E * np.r_[1.5, 1.5, 1.5, 1.0, 1.0, 1.0]  # 50 % more translation error, the same rotations
    c = compare_modes({"joint": _run(J), "sequential": _run(E)})["talus"]
    assert c["mm"]["paired"]["verdict"] == "worse" and not c["mm"]["paired"]["at_least_as_good"]
    assert c["deg"]["paired"]["at_least_as_good"] and not c["at_least_as_good"]
    assert c["mm"]["ratio"] == pytest.approx(1.5)


@pytest.mark.parametrize(("excess", "met"), [(0.99, True), (1.01, False)])
def test_the_margin_is_an_eighth_of_the_bound(excess, met):
    """Constant errors: the bootstrap interval is the difference itself, just inside or outside
    0.1 × 1.25 × the bound (0.005 mm of 0.04 mm)."""
    n, a = 40, 0.03
    seq = np.tile([a, 0, 0, 0.1, 0, 0], (n, 1))
    joint = np.tile([a + excess * 0.125 * 0.04, 0, 0, 0.1, 0, 0], (n, 1))
    c = compare_modes({"joint": _run(joint), "sequential": _run(seq)})["talus"]
    lo, hi = c["mm"]["paired"]["interval95"]
    assert lo == pytest.approx(hi, abs=1e-9) and hi == pytest.approx(excess * 0.005, abs=1e-6)
    assert c["mm"]["paired"]["verdict"] == "worse" and c["at_least_as_good"] is met


def test_frames_are_paired_by_their_number_and_without_a_bound_the_rms_decide():
    E = _errors(10)
    J = E.copy()
    J[3] *= 10  # frame 3 of joint is bad, but sequential has no pose there
    js = _run(np.delete(E, 3, axis=0), frames=[f for f in range(10) if f != 3])
    c = compare_modes({"joint": _run(J, frames=list(range(10))), "sequential": js})["talus"]
    assert c["mm"]["paired"]["n_frames"] == 9 and c["mm"]["paired"]["rms_difference"] == 0.0
    unplaced = _run(np.delete(E, 3, axis=0))
    unplaced["config"]["frames"] = 10  # 9 errors of 10 frames and no frame numbers: not paired
    c = compare_modes({"joint": _run(E), "sequential": unplaced})["talus"]
    assert c["decided_on"] == "rms" and "paired" not in c["mm"]
    one = _run(E)
    del one["tracking"]["talus"]["cramer_rao"]
    c = compare_modes({"joint": one, "sequential": one})["talus"]
    assert c["decided_on"] == "rms" and c["at_least_as_good"]


def test_sigma_coverage_is_checked_per_axis_on_the_stored_frames():
    E = _errors(200, seed=3, scale=(0.03, 0.2))
    sig = [[0.03] * 3 + [0.05] * 3 for _ in E]  # right for translation, 4× too small for rotation
    sig[0] = None  # a frame without σ (no confidence computed): left out of the coverage, counted
    t = {**_bone(0.05, 0.3), **_run(E, sigma=sig)["tracking"]["talus"]}
    g = goals({"talus": t})["talus"]
    tr, rot = g["within_2_sigma_translation"], g["within_2_sigma_rotation"]
    assert 0.9 < tr[0] < 1.0 and tr[1] and rot[0] < 0.6 and not rot[1]
    cov = g["sigma_coverage"]
    assert cov["per_axis"]["expected"] == pytest.approx(0.9545) and cov["frames_without_sigma"] == 1
    assert cov["n_frames"] == len(E) - 1 and cov["per_axis"]["translation"]["n"] == 3 * (len(E) - 1)
    assert cov["z_rms"]["tx"] == pytest.approx(1.0, abs=0.15) and cov["z_rms"]["rx"] > 3
    assert "within_2_sigma" not in g


def test_frames_without_sigma_do_not_count_as_covered():
    """A run without confidence (every frame's σ None, e.g. tracked with confidence off) has no
    coverage to check: the goal is not met (it was 100 % met, each frame counted within an infinite
    σ). Frames without σ among others are left out, not counted inside: errors 3 σ off in the frames
    that have one are not covered whatever the frames without."""
    E = _errors(50, seed=4)
    none = {**_bone(0.05, 0.3, inside=None), **_run(E, sigma=[None] * len(E))["tracking"]["talus"]}
    g = goals({"talus": none})["talus"]
    assert g["within_2_sigma"] == [None, False] and "within_2_sigma_translation" not in g
    sig = [None] * 40 + [[0.01] * 3 + [0.0666] * 3] * 10  # 10 frames with σ, their errors ~3 σ
    part = {**_bone(0.05, 0.3), **_run(E, sigma=sig)["tracking"]["talus"]}
    g = goals({"talus": part})["talus"]
    assert g["sigma_coverage"]["frames_without_sigma"] == 40 and g["sigma_coverage"]["n_frames"] == 10
    assert g["within_2_sigma_translation"][0] < 0.9 and not g["within_2_sigma_translation"][1]
    assert g["within_2_sigma_rotation"][0] < 0.9 and not g["within_2_sigma_rotation"][1]
    # an axis without σ (None) is unbounded on that axis: covered there, the frame kept
    one_axis = [[None] + [0.03] * 2 + [0.2] * 3 for _ in E]
    t = {**_bone(0.05, 0.3), **_run(E, sigma=one_axis)["tracking"]["talus"]}
    cov = goals({"talus": t})["talus"]["sigma_coverage"]
    assert cov["n_frames"] == len(E) and cov["frames_without_sigma"] == 0
    assert cov["per_axis"]["axes"]["tx"] == 1.0


def _drift(seed):
    E = _errors(30, seed)
    runs = {m: {"talus": {"rms_mm": 0.03, "rms_deg": 0.2, "per_frame_error": (E * f).tolist(),
                          "frames": list(range(30))}}
            for m, f in (("sequential", 2.0), ("sequential_subtracted", 1.0), ("joint", 1.0))}
    return {"study": "core.studies.tracking.sequential_drift", "frames": 30, "seed": seed,
            "bound": {"source": "compute", "talus": {"rms_mm": 0.04, "rms_deg": 0.16}}, "runs": runs}


def test_regoal_rewrites_the_goals_of_a_stored_file_and_keeps_the_rest(tmp_path):
    import json

    from core.studies.tracking.acceptance_goals import main

    E = _errors()
    runs = {m: _run(E * f, sigma=[[0.05] * 6] * len(E)) for m, f in (("joint", 1.0), ("sequential", 1.01))}
    for r in runs.values():
        r["tracking"]["talus"].update(_bone(0.05, 0.3))
        r["goals"] = {"talus": {"within_2_sigma": [0.95, True]}}
    d = {"study": "core.studies.tracking.acceptance", "commit": "abc", "modes": ["joint", "sequential"],
         "runs": runs, "joint_vs_sequential": {"talus": {"mm": {"ratio": 1.0}}}}
    f = tmp_path / "r.json"
    f.write_text(json.dumps(d, indent=1))
    assert main(["--regoal", str(f)]) == 0
    text = f.read_text()
    out = json.loads(text)
    assert text.startswith('{\n "study"') and not text.endswith("\n")  # written as it was stored
    assert out["commit"] == "abc" and out["runs"]["joint"]["tracking"] == d["runs"]["joint"]["tracking"]
    assert "within_2_sigma_rotation" in out["runs"]["sequential"]["goals"]["talus"]
    assert out["joint_vs_sequential"]["talus"]["at_least_as_good"]
    assert out["regoal"]["rewritten"] == ["runs.joint.goals", "runs.sequential.goals", "joint_vs_sequential"]
    assert out["regoal"]["command"].endswith(f"--regoal {f}") and out["regoal"]["commit"]
    # a one-mode file paired with the other mode's run of the same trial
    seq = {"study": "core.studies.tracking.acceptance", **runs["sequential"],
           "config": {"mode": "sequential", "frames": len(E), "pixels": 64}}
    jf = tmp_path / "j.json"
    joint = {**runs["joint"], "config": {"mode": "joint", "frames": len(E), "pixels": 64}}
    jf.write_text(json.dumps({"runs": {"joint": joint}}))
    sf = tmp_path / "s.json"
    sf.write_text(json.dumps(seq, indent=2) + "\n")
    assert main(["--regoal", str(sf), "--joint-from", str(jf), "--out", str(tmp_path / "o.json")]) == 0
    o = json.loads((tmp_path / "o.json").read_text())
    assert o["joint_vs_sequential"]["talus"]["decided_on"] == "paired"
    assert o["regoal"]["joint_from"] == str(jf)
    assert json.loads(sf.read_text()) == seq  # --out: the stored file untouched
    jf.write_text(json.dumps({"runs": {"joint": {**joint, "config": {"mode": "joint", "frames": 7}}}}))
    with pytest.raises(ValueError, match="same trial"):
        main(["--regoal", str(sf), "--joint-from", str(jf), "--out", str(tmp_path / "o.json")])


def test_regoal_of_sequential_drift_seeds_compares_per_seed_and_pooled(tmp_path):
    import json

    from core.studies.tracking.acceptance_goals import main

    d = {"study": "core.studies.tracking.sequential_drift",
         "runs": {"seed_1": _drift(1), "seed_2": _drift(2)}}
    f = tmp_path / "d.json"
    f.write_text(json.dumps(d, indent=1))
    main(["--regoal", str(f)])
    out = json.loads(f.read_text())
    for k in ("seed_1", "seed_2"):
        c = out["runs"][k]["joint_vs_sequential"]
        assert c["subtracted"]["talus"]["at_least_as_good"] and c["subtracted"]["talus"]["mm"]["ratio"] == 1.0
        assert c["whole_image"]["talus"]["mm"]["paired"]["verdict"] == "better"
    pooled = out["joint_vs_sequential"]["seeds_pooled"]
    assert pooled["subtracted"]["talus"]["mm"]["n_frames"] == 60
    assert pooled["subtracted"]["talus"]["seeds"] == 2
    assert pooled["whole_image"]["talus"]["at_least_as_good"]
    assert pooled["whole_image"]["talus"]["mm"]["ratio"] == pytest.approx(0.5, rel=1e-3)  # of 5-digit RMS
