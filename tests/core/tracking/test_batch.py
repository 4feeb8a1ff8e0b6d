"""``core.tracking.batch``: tasks of a study, and a batch on a local Dask cluster of 2 CPU worker
processes that gives the poses of a serial run, even when one worker is killed mid-run."""

from __future__ import annotations

import os
import shutil
import signal

import numpy as np
import pytest

from core.study import Study, StudyError
from core.tracking.batch import BatchTask, TaskSettings, build_tasks, run_serial, summarize, tracks_jointly
from core.tracking.register import Level, RegistrationOptions
from tests.core.tracking.batch_helpers import save_flat_calibration

BONES = ("talus", "calcaneus")
FRAMES = 2  # tracked per task, of the demo's 30 (the worker killed after its first has 1 to go)
# one short CMA-ES level per frame, the first-frame verification restarts left out: a small,
# quick batch (a frame of these 48² views costs 0.2-1 s of CPU; with the default options, and
# the 2-frame walk this test had before, every frame was retried, about 2.5 s each)
_FAST = RegistrationOptions(bounds=(5.0, 5.0), refine="pattern", levels=(
    Level(1.0, "cmaes", (1.0, 1.0), popsize=10, max_generations=40, tol_x=0.02),))
SETTINGS = TaskSettings(device="cpu", confidence=False, frames=(0, FRAMES), options=(
    ("verify_restarts", 0), ("registration", _FAST), ("first", _FAST)))


@pytest.fixture(scope="module")
def demo(tmp_path_factory, demo_walk_48):
    """A demo study of 2 trials (the second on the first one's frames) × 2 bones with keyframes:
    a copy of the 30-frame walk (the bones move little from frame to frame), walk2 added."""
    out = shutil.copytree(demo_walk_48, tmp_path_factory.mktemp("batch") / "demo")
    with Study.open(out, mode="w") as st:
        walk = st.manifest["trials"]["walk"]
        st.add_trial("walk2", [st.path(v["path"]) for v in walk["views"]], calibration=walk["calibration"],
                     bones=list(BONES), bit_depth=walk["views"][0]["bit_depth"])
        for b in BONES:
            st.trial("walk2").record_pose(b, 0, st.trial("walk").poses(b)[0])  # the same keyframe
    return out


def _copy(demo, dest):
    shutil.copytree(demo, dest)
    return dest


def test_build_tasks(demo):
    tasks = build_tasks([demo], bones=list(BONES))
    assert [t.key for t in tasks] == ["demo/walk/talus", "demo/walk/calcaneus",
                                      "demo/walk2/talus", "demo/walk2/calcaneus"]
    assert tasks[0] == BatchTask(str(demo.absolute()), "walk", ("talus",))
    assert tasks[0].report_name == "walk.talus"
    joint = build_tasks([demo], trials=["walk2"], joint=True)
    assert [(t.trial, t.bones) for t in joint] == [("walk2", BONES)]
    assert joint[0].report_name == "walk2"  # the trial's report, as talus track writes it
    assert len(build_tasks([demo, demo], trials=["walk"])) == 8  # every bone of walk, twice
    with pytest.raises(ValueError, match=r"--trials: \['run'\] not found"):
        build_tasks([demo], trials=["walk", "run"])
    with pytest.raises(ValueError, match=r"--bones: \['ulna'\] not found"):
        build_tasks([demo], bones=["ulna"])


@pytest.fixture(scope="module")
def calibrated(demo, tmp_path_factory):
    """The demo with walk's frames flatfield-corrected by a saved calibration (walk2's not)."""
    out = _copy(demo, tmp_path_factory.mktemp("calibrated") / "demo")
    save_flat_calibration(out, ["walk"])
    return out


def test_build_tasks_mode_auto_tracks_as_talus_track(demo, calibrated):
    # auto (the default): jointly where the frames are flatfield-corrected, as track_study's mode
    # "auto" tracks them; one task per bone where they are divided by the full scale only
    with Study.open(demo) as st:
        assert not tracks_jointly(st, "walk")
    with Study.open(calibrated) as st:
        assert tracks_jointly(st, "walk") and not tracks_jointly(st, "walk2")
    tasks = build_tasks([calibrated], bones=list(BONES))
    assert [t.key for t in tasks] == ["demo/walk/talus+calcaneus", "demo/walk2/talus", "demo/walk2/calcaneus"]
    assert build_tasks([calibrated], bones=["talus"]) == [BatchTask(str(calibrated.absolute()), t, ("talus",))
                                                          for t in ("walk", "walk2")]
    # the overrides, and joint=True/False for mode joint/sequential (a trial's bones in one task,
    # tracked one after another as talus track --mode sequential; split_bones: a task per bone)
    seq = [(t.trial, t.bones, t.tracking_mode) for t in build_tasks([calibrated], bones=list(BONES),
                                                                    mode="sequential")]
    assert seq == [(t, BONES, "sequential") for t in ("walk", "walk2")]
    assert [(t.trial, t.bones, t.tracking_mode) for t in build_tasks([calibrated], bones=list(BONES),
                                                                     joint=False)] == seq
    per_bone = [(t.trial, t.bones) for t in build_tasks([calibrated], bones=list(BONES), mode="sequential",
                                                        split_bones=True)]
    assert per_bone == [(t, (b,)) for t in ("walk", "walk2") for b in BONES]
    assert [t.bones for t in build_tasks([demo], bones=list(BONES), mode="joint")] == [BONES, BONES]
    assert build_tasks([demo], bones=list(BONES), joint=True) == build_tasks([demo], bones=list(BONES),
                                                                             mode="joint")
    with pytest.raises(ValueError, match="mode: expected one of"):
        build_tasks([demo], mode="together")
    with pytest.raises(ValueError, match="joint: joint=True contradicts mode='sequential'"):
        build_tasks([demo], joint=True, mode="sequential")
    # frame ranges: the auto joint group splits where both bones have a keyframe (frame 0 only)
    ranged = build_tasks([calibrated], trials=["walk"], bones=list(BONES), ranges=True, frames=(0, 3))
    assert [(t.bones, t.frames) for t in ranged] == [(BONES, (0, 2))]


def test_an_unreadable_correction_fails_its_own_task_only(calibrated, tmp_path):
    """A trial whose saved correction cannot be read does not stop build_tasks: it gets one joint
    task (which fails when run, naming the file, as talus track would); the other trials as usual."""
    out = _copy(calibrated, tmp_path / "demo")
    for p in (out / "calibrations").rglob("correction_cam1.json"):
        p.write_text("{ not json", encoding="utf-8")
    with Study.open(out) as st, pytest.raises(StudyError):
        tracks_jointly(st, "walk")
    tasks = build_tasks([out], bones=list(BONES))
    assert [t.key for t in tasks] == ["demo/walk/talus+calcaneus", "demo/walk2/talus", "demo/walk2/calcaneus"]


def test_tracks_jointly_is_track_studys_auto_rule(calibrated, tmp_path, monkeypatch):
    """What build_tasks(mode="auto") groups, track_study(mode="auto") tracks jointly (its registration
    stubbed), also for a correction in the study settings (walk2's frames then count as corrected)."""
    import types

    import core.render
    from core.imaging.pipeline import Pipeline
    from core.tracking import from_study
    from core.tracking.trial import TrackingOptions, TrackingResult

    seen = {}
    monkeypatch.setattr(core.render, "DRRRenderer", lambda *a, **kw: types.SimpleNamespace())

    def track(renderer, bones, frames, order, *, options=None, **kw):
        seen["mode"] = options.mode
        return TrackingResult(tuple(b.name for b in bones), tuple(order), {}, "complete", 0.0)

    monkeypatch.setattr(from_study, "track", track)
    folder = _copy(calibrated, tmp_path / "demo")
    for settings in (False, True):
        if settings:
            with Study.open(folder, mode="w") as st:
                st.update_settings(correction={"views": [Pipeline().to_dict()] * 2})
        for t in ("walk", "walk2"):
            with Study.open(folder, mode="w") as st:
                from_study.track_study(st, t, list(BONES), [0], options=TrackingOptions(mode="auto"))
                joint = tracks_jointly(st, t)
            assert seen["mode"] == ("joint" if joint else "sequential"), (t, settings)
            assert joint == (t == "walk" or settings)
    assert [t.bones for t in build_tasks([folder], bones=list(BONES))] == [BONES, BONES]


def test_an_auto_joint_task_tracks_its_bones_jointly(calibrated, tmp_path):
    folder = _copy(calibrated, tmp_path / "demo")
    one = TaskSettings(device="cpu", confidence=False, frames=(0, 1), options=SETTINGS.options)
    s = run_serial(build_tasks([folder], trials=["walk"], bones=list(BONES)), one)
    assert s["status"] == "complete" and s["frames_tracked"] == 2, s
    assert s["task_records"][0]["mode"] == "joint"
    with Study.open(folder) as st:
        rep = st.read_report("tracking", "walk")
    assert rep["options"]["mode"] == "joint" and rep["normalisation"] == "saved with calibration flat.v1"


def test_summary_reports_failures():
    t = [BatchTask("/s", "walk", ("talus",)), BatchTask("/s", "walk", ("tibia",))]
    rec = {"key": t[0].key, "status": "complete", "seconds": 2.0, "frames_tracked": 4,
           "frames_recorded": 4}
    s = summarize(t, [rec], [{"key": t[1].key, "error": "ValueError: bad", "attempts": 2}],
                  wall_s=4.0, workers=2, attempts={t[0].key: 1, t[1].key: 2})
    assert s["status"] == "failed" and s["tasks"] == 2 and s["tasks_failed"] == 1
    assert s["failures"] == [{"key": "s/walk/tibia", "error": "ValueError: bad", "attempts": 2}]
    assert s["frames_tracked"] == 4 and s["frames_per_s"] == 1.0


def test_throughput_model_is_a_longest_task_first_makespan():
    from core.studies.batch.benchmark import model

    one = {"task_s": [4.0, 3.0, 2.0, 1.0], "scheduling_s_per_task": 0.5, "cluster_startup_s": 1.0,
           "frames_tracked": 20, "wall_s": 13.0}
    m = {r["workers"]: r for r in model(one, counts=(1, 2, 4, 8))}
    assert m[1]["wall_s"] == 13.0 and m[1]["speed_up"] == 1.0  # 1 + 4.5 + 3.5 + 2.5 + 1.5
    assert m[2]["wall_s"] == 7.0  # {4.5, 1.5} and {3.5, 2.5}
    assert m[4]["wall_s"] == m[8]["wall_s"] == 5.5  # the longest task bounds it
    assert m[2]["frames_per_s"] == round(20 / 7.0, 4)


def test_batch_on_two_workers_matches_serial_and_survives_a_killed_worker(demo, tmp_path):
    pytest.importorskip("distributed")
    from core.tracking.batch import run_batch

    serial_dir, batch_dir = _copy(demo, tmp_path / "serial"), _copy(demo, tmp_path / "batch")
    # the two bones of one trial, a task each: one per worker (the trial walk2 doubled the frames)
    serial = run_serial(build_tasks([serial_dir], trials=["walk"], bones=list(BONES)), SETTINGS)
    assert serial["status"] == "complete" and serial["frames_tracked"] == 2 * FRAMES

    killed, events, started = [], [], []

    def on_event(e):
        events.append(e)
        if e["kind"] == "frame" and not killed:  # a worker dies after its first frame
            killed.append((e["key"], e["pid"]))
            os.kill(e["pid"], signal.SIGKILL)

    summary = run_batch(build_tasks([batch_dir], trials=["walk"], bones=list(BONES)), SETTINGS, workers=2,
                        on_event=on_event, on_start=started.append)
    assert started and started[0]["workers"] == 2 and started[0]["dashboard"].startswith("http")
    assert summary["status"] == "complete" and summary["tasks_complete"] == 2, summary
    assert summary["failures"] == [] and summary["workers"] == 2
    rows = {r["key"]: r for r in summary["task_records"]}
    assert killed
    key, pid = killed[0]
    seen = [(r["key"], r["pid"], r["attempts"], r["frames_resumed"], r["frames_tracked"])
            for r in rows.values()]
    # run again in another process: the other worker, or the killed one once its nanny has restarted
    # it. Which of them, and whether the restarted worker gets any task at all, is a race: from the
    # kill to the restarted worker's first task took 2.5-21 s in 30 runs at load averages of 4-13
    # on this 2-core machine, about as long as the other worker's remaining tasks (when it takes
    # them all, every task record has that worker's pid)
    assert rows[key]["attempts"] == 2 and rows[key]["pid"] != pid, (pid, seen)
    assert rows[key]["frames_resumed"] >= 1, seen  # the frame done before the kill was kept
    assert rows[key]["frames_tracked"] == FRAMES - rows[key]["frames_resumed"], seen
    assert {e["kind"] for e in events} == {"start", "frame", "end"}
    with Study.open(serial_dir) as a, Study.open(batch_dir) as b:
        for t in ("walk",):
            for bone in BONES:
                pa, pb = a.trial(t).poses(bone), b.trial(t).poses(bone)
                assert np.isfinite(pb[:FRAMES]).all(), (t, bone)  # nothing lost
                np.testing.assert_allclose(pb, pa, rtol=0, atol=1e-9, err_msg=f"{t}/{bone}")
                rep = b.read_report("tracking", f"{t}.{bone}")
                assert rep["summary"]["status"] == "complete"


def test_task_settings_metric_names_as_talus_track():
    from core.tracking.cost import DEFAULT_TERMS, metric_terms

    assert TaskSettings().tracking_options(joint=False).registration.terms == DEFAULT_TERMS
    comp = TaskSettings(metric="components").tracking_options(joint=True).registration.terms
    assert comp == metric_terms("components") and comp[0].options["components"] is True
    assert metric_terms("magnitudes") == metric_terms("gc") == DEFAULT_TERMS
    ncc = TaskSettings(metric="ncc").tracking_options(joint=False).registration.terms
    assert [t.kind for t in ncc] == ["ncc"]
