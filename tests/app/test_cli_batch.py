"""``talus batch``: the command wires core.tracking.batch (tasks, progress lines, JSON summary,
exit statuses); the Dask runs themselves are tested in tests/core/tracking/test_batch.py."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import pytest

from app.commands import batch
from app.commands._shared import EXIT_ERROR, EXIT_OK, CliError, report_error


def talus_batch(argv: list[str]) -> int:
    p = argparse.ArgumentParser(prog="talus batch")
    batch.configure(p)
    a = p.parse_args(argv)
    try:
        return a.run(a)
    except Exception as exc:
        return report_error(exc, "batch")


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    """A 30-frame demo walk (the bones move little from frame to frame; 2 are tracked): this
    module's copy of the one the process built (:func:`tests.core.tracking.demo_walk.built`)."""
    import shutil

    from tests.core.tracking.demo_walk import built

    return Path(shutil.copytree(built(tmp_path_factory), tmp_path_factory.mktemp("demo") / "demo"))


@pytest.fixture
def fast_tracking(monkeypatch):
    """The command's tasks track with one short CMA-ES level per frame and no verifying restarts
    (this tests the command's wiring; at these 48² views the default search stalls and every
    frame is retried)."""
    from dataclasses import replace

    from core.tracking.batch import TaskSettings
    from core.tracking.register import Level, RegistrationOptions

    fast = RegistrationOptions(bounds=(5.0, 5.0), refine="pattern", levels=(
        Level(1.0, "cmaes", (1.0, 1.0), popsize=10, max_generations=40, tol_x=0.02),))
    built = TaskSettings.tracking_options

    def tracking_options(self, joint):
        return replace(built(self, joint), registration=fast, first=fast, verify_restarts=0)

    monkeypatch.setattr(TaskSettings, "tracking_options", tracking_options)


def test_batch_without_dask_tracks_journals_and_summarises(demo, capsys, fast_tracking):
    from core.study import Study

    rc = talus_batch([str(demo), "--trials", "walk", "--bones", "talus,calcaneus", "--frames", "0:2",
                      "--workers", "0", "--device", "cpu", "--no-confidence"])
    out = capsys.readouterr()
    assert rc == EXIT_OK, out.err
    s = json.loads(out.out)
    assert s["status"] == "complete" and s["tasks"] == 2 and s["frames_tracked"] == 4
    assert [r["key"] for r in s["task_records"]] == [f"{demo.name}/walk/talus", f"{demo.name}/walk/calcaneus"]
    assert all(r["attempts"] == 1 and r["seconds"] > 0 for r in s["task_records"])
    assert "2 tasks:" in out.err and "frame 2/2" in out.err and "complete in" in out.err
    with Study.open(demo) as st:
        for b in ("talus", "calcaneus"):
            assert np.isfinite(st.trial("walk").poses(b)[:2]).all()
            assert st.read_report("tracking", f"walk.{b}")["summary"]["status"] == "complete"
    # run again: everything is in the journals already, nothing is tracked
    rc = talus_batch([str(demo), "--trials", "walk", "--bones", "talus", "--frames", "0:2",
                      "--workers", "0", "--device", "cpu", "--quiet"])
    s = json.loads(capsys.readouterr().out)
    assert rc == EXIT_OK and s["frames_tracked"] == 0 and s["task_records"][0]["frames_resumed"] == 2


@pytest.fixture
def planned(monkeypatch):
    """The command's tasks, not run: each --workers 0 run records its tasks and reports them done."""
    import core.tracking.batch as core_batch

    seen = []

    def run_serial(tasks, settings=None, *, progress=None, cancel=None):
        seen.append([t.key for t in tasks])
        recs = [dict(key=t.key, study=t.study, trial=t.trial, bones=list(t.bones), status="complete",
                     seconds=0.0) for t in tasks]
        return core_batch.summarize(tasks, recs, [], wall_s=0.1, workers=0)

    monkeypatch.setattr(core_batch, "run_serial", run_serial)
    return seen


def test_batch_mode_auto_tracks_as_talus_track(demo, tmp_path, capsys, planned):
    import shutil

    from core.tracking.batch import MODES
    from tests.core.tracking.batch_helpers import save_flat_calibration

    assert batch.MODES == MODES
    calibrated = shutil.copytree(demo, tmp_path / "calibrated")
    save_flat_calibration(calibrated, ["walk"])
    common = ["--trials", "walk", "--bones", "talus,calcaneus", "--workers", "0", "--quiet"]
    runs = {  # (study, arguments) -> tasks
        (calibrated, ()): ["calibrated/walk/talus+calcaneus"],  # the default: as talus track, jointly
        # sequential: the trial's bones one after another in one task, as talus track --mode sequential
        (calibrated, ("--mode", "sequential")): ["calibrated/walk/talus+calcaneus"],
        (calibrated, ("--mode", "sequential", "--split-bones")): ["calibrated/walk/talus",
                                                                  "calibrated/walk/calcaneus"],
        (demo, ()): [f"{demo.name}/walk/talus", f"{demo.name}/walk/calcaneus"],  # no flatfield
        # no flatfield, the neighbours asked subtracted: one sequential task, as talus track does
        (demo, ("--sequential-subtract", "on")): [f"{demo.name}/walk/talus+calcaneus"],
        (demo, ("--mode", "joint")): [f"{demo.name}/walk/talus+calcaneus"],
        (demo, ("--joint",)): [f"{demo.name}/walk/talus+calcaneus"],
        (demo, ("--joint", "--mode", "joint")): [f"{demo.name}/walk/talus+calcaneus"],
    }
    for (study, args), keys in runs.items():
        assert talus_batch([str(study), *common, *args]) == EXIT_OK, capsys.readouterr().err
        assert planned[-1] == keys, args
        assert [r["key"] for r in json.loads(capsys.readouterr().out)["task_records"]] == keys
    rc = talus_batch([str(calibrated), "--trials", "walk", "--bones", "talus,calcaneus", "--workers", "0"])
    assert rc == EXIT_OK
    err = capsys.readouterr().err
    assert "mode auto (jointly where the frames are flatfield-corrected): bones tracked jointly in walk" \
        in err
    assert talus_batch([str(demo), "--joint", "--mode", "sequential", "--workers", "0"]) == EXIT_ERROR
    assert "--joint: contradicts --mode sequential" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        talus_batch([str(demo), "--mode", "together"])
    assert "invalid choice: 'together'" in capsys.readouterr().err


def test_batch_bad_input(demo, tmp_path, capsys):
    assert talus_batch([str(tmp_path / "nowhere")]) == EXIT_ERROR
    assert "no study folder" in capsys.readouterr().err
    assert talus_batch([str(demo), "--trials", "run"]) == EXIT_ERROR
    assert "--trials: ['run'] not found" in capsys.readouterr().err
    assert talus_batch([str(demo), "--frames", "2:1", "--workers", "0"]) == EXIT_ERROR
    assert "--frames" in capsys.readouterr().err
    with pytest.raises(CliError, match="--workers"):
        p = argparse.ArgumentParser()
        batch.configure(p)
        a = p.parse_args([str(demo), "--workers", "0", "--scheduler", "tcp://h:8786"])
        a.run(a)


def test_batch_final_likelihood(demo, capsys, monkeypatch):
    """--final likelihood: refused naming the trial on frames without flatfield (the demo's), else
    every task's options end with the final stage (the tasks are not run here)."""
    assert talus_batch([str(demo), "--workers", "0", "--final", "likelihood", "--quiet"]) == EXIT_ERROR
    err = capsys.readouterr().err
    assert "--final likelihood" in err and "trial 'walk'" in err and "not flatfield-corrected" in err
    import core.tracking.batch as core_batch

    seen = []

    def fake_run_serial(tasks, settings, progress=None):
        seen.append(settings)
        return {"status": "complete", "failures": []}

    monkeypatch.setattr(core_batch, "run_serial", fake_run_serial)
    monkeypatch.setattr(batch, "final_stage_problems", lambda tasks: [])  # as flatfield trials
    assert talus_batch([str(demo), "--workers", "0", "--quiet"]) == EXIT_OK
    assert talus_batch([str(demo), "--workers", "0", "--final", "likelihood", "--quiet"]) == EXIT_OK
    capsys.readouterr()
    plain, final = (s.tracking_options(joint=False) for s in seen)
    assert plain.registration.final is None and not plain.refine_likelihood
    assert final.refine_likelihood and final.registration.final == "likelihood"
    assert final.first_options.final == "likelihood"


def test_talus_batch_is_registered(tmp_path, capsys):
    from app.cli import main

    assert main(["batch", str(tmp_path / "nowhere")]) == EXIT_ERROR
    assert "talus batch: error: STUDY: no study folder" in capsys.readouterr().err


def test_batch_ranges_print_the_trajectory_check_over_each_trials_ranges(demo, tmp_path, capsys, monkeypatch):
    """--ranges: the summary's task records and stderr give the flags after the check that judges a
    trial's ranges together (the registration replaced by smooth poses, frame 10 0.2 deg off: the
    range 12-0 alone does not flag it, the whole trial does)."""
    import shutil

    from core.study import Study
    from core.tracking import trial
    from core.tracking.results import FrameResult
    from tests.core.tracking.test_flags_post import _track

    folder = shutil.copytree(demo, tmp_path / "keyed")
    with Study.open(folder, mode="w") as st:
        t = st.trial("walk")
        for f in list(t.results("talus").records):
            t.clear_pose("talus", f)
        t.record_pose("talus", 12, np.load(folder / "poses" / "talus.npy")[12])
    P = _track(n=30, off=(10, 0.0, 0.2))
    from functools import partial

    from core.tracking import flags_post

    # the trial's ends cut (ends=False): with flags_ends the range flags frame 10 itself
    monkeypatch.setattr(flags_post, "trajectory_review", partial(flags_post.trajectory_review, ends=False))
    monkeypatch.setattr(trial, "track_frame", lambda run, f, imgs, fr, todo, state, skip: {
        0: FrameResult("talus", f, P[f], 0.8, 10, 0.0, True)})
    rc = talus_batch([str(folder), "--bones", "talus", "--ranges", "--workers", "0", "--device", "cpu",
                      "--no-confidence", "--quiet"])
    out = capsys.readouterr()
    assert rc == EXIT_OK, out.err
    s = json.loads(out.out)
    assert [(r["key"], r["flagged_before_pass"], r["flagged"]) for r in s["task_records"]] == [
        ("keyed/walk/talus:12-0", 0, 1), ("keyed/walk/talus:12-29", 0, 0)]
    line = ("talus batch: keyed/walk/talus: 1 flagged for review after the trajectory check over its 2 "
            "ranges together (30 bone-frames judged, 1 off the trajectory, 1 changed by the check)")
    assert line in out.err
    assert "talus batch: keyed/walk/talus: talus frame 10: off the trajectory" in out.err


def test_sequential_mode_is_one_task_per_trial_and_says_what_it_subtracted(tmp_path_factory, capsys,
                                                                           fast_tracking, monkeypatch,
                                                                           tmp_path):
    """--mode sequential: a trial's bones in one task, tracked one after another as talus track --mode
    sequential (on these frames, divided by the full scale, auto subtracts nothing: said on stderr and
    in the record); --split-bones: a task per bone, and stderr says it cannot subtract; refused
    outside --mode sequential."""
    import shutil

    from tests.core.tracking.demo_walk import built

    folder = shutil.copytree(built(tmp_path_factory), tmp_path / "demo")  # nothing tracked yet
    rc = talus_batch([str(folder), "--trials", "walk", "--bones", "talus,calcaneus", "--frames", "0:1",
                      "--workers", "0", "--device", "cpu", "--no-confidence", "--quiet",
                      "--mode", "sequential"])
    out = capsys.readouterr()
    assert rc == EXIT_OK, out.err
    (rec,) = json.loads(out.out)["task_records"]
    assert rec["key"] == "demo/walk/talus+calcaneus" and rec["mode"] == "sequential"
    assert rec["sequential_subtract"] is False and rec["frames_tracked"] == 2
    assert "talus batch: demo/walk/talus+calcaneus: sequential, neighbours not subtracted" in out.err
    import core.tracking.batch as core_batch

    seen = []

    def fake_run_serial(tasks, settings, progress=None):
        seen.append(tasks)
        note = "on, but no other bone tracked: nothing to subtract"
        return {"status": "complete", "failures": [], "task_records": [
            {"key": t.key, "mode": "sequential", "sequential_subtract": False,
             "sequential_subtract_note": note} for t in tasks]}

    monkeypatch.setattr(core_batch, "run_serial", fake_run_serial)
    rc = talus_batch([str(folder), "--bones", "talus,calcaneus", "--workers", "0", "--mode", "sequential",
                      "--split-bones", "--trials", "walk"])
    err = capsys.readouterr().err
    assert rc == EXIT_OK and [t.bones for t in seen[0]] == [("talus",), ("calcaneus",)]
    assert "--split-bones: one task per bone, each searched against the whole image" in err
    assert ("demo/walk/calcaneus: sequential, neighbours not subtracted (on, but no other bone tracked: "
            "nothing to subtract)") in err
    assert talus_batch([str(folder), "--workers", "0", "--split-bones"]) == EXIT_ERROR
    assert "--split-bones: one task per bone is a choice of --mode sequential, not --mode auto" in (
        capsys.readouterr().err)


def test_a_batch_tracks_with_talus_tracks_options():
    """The default task settings give the TrackingOptions of talus track --mode sequential (joint), so
    a sequential task, which calls the same track_study, gives its poses."""
    from app.commands.track import options_from_choices
    from core.tracking.batch import TaskSettings

    for joint, mode in ((False, "sequential"), (True, "joint")):
        assert TaskSettings().tracking_options(joint=joint) == options_from_choices(mode=mode)


#: A group the trajectory check did not judge (it is off) whose shared keyframe's merge failed after
#: journaling one frame: ``shared_error`` (core.tracking.batch_pass.run_pass).
SHARED_ERROR = {"key": "study/walk/talus", "ranges": ["study/walk/talus:12-0", "study/walk/talus:12-29"],
                "judged": 0, "flagged": 0, "changed": [], "seconds": 0.0, "off": True,
                "shared_error": "LockedError: walk.talus is being written by another process",
                "journaled": [["talus", 12]], "changed_total": 2}


def test_batch_prints_a_failed_merge_of_the_shared_keyframe(demo, capsys, monkeypatch):
    """The pass's ``shared_error`` (the trajectory check off, the merge of the keyframe two ranges share
    failed): stderr gives the lines the window shows as error messages (the tasks recorded, not run)."""
    import core.tracking.batch as core_batch
    from app.tracking_actions import MAX_FLAG_MESSAGES
    from core.tracking.batch_pass import pass_messages

    def run_serial(tasks, settings=None, *, progress=None, cancel=None):
        recs = [dict(key=t.key, study=t.study, trial=t.trial, bones=list(t.bones), status="complete",
                     seconds=0.0) for t in tasks]
        return dict(core_batch.summarize(tasks, recs, [], wall_s=0.1, workers=0),
                    trajectory_pass=[SHARED_ERROR])

    monkeypatch.setattr(core_batch, "run_serial", run_serial)
    rc = talus_batch([str(demo), "--trials", "walk", "--bones", "talus", "--workers", "0", "--quiet"])
    out = capsys.readouterr()
    assert rc == EXIT_OK, out.err
    lines = pass_messages(SHARED_ERROR, limit=MAX_FLAG_MESSAGES)
    assert lines == pass_messages(SHARED_ERROR) and "not merged (LockedError" in lines[1]
    for line in lines:  # as the window's messages, "Batch: " there
        assert f"talus batch: {line}\n" in out.err
