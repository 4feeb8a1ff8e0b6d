"""``core.tracking.batch`` frame-range tasks: ranges between keyframes, run side by side on a local
Dask cluster of 2 CPU worker processes into one bone's journal, give the poses of a serial run of
the same ranges (``track_study`` over each range, as ``talus track --frames --resume`` does), and a
second run resumes everything from the journal."""

from __future__ import annotations

import shutil

import numpy as np
import pytest

from core.io.atomic import LockedError
from core.study import Study
from core.tracking import batch_journal
from core.tracking.batch import BatchTask, TaskSettings, build_tasks, keyframe_ranges, run_serial, run_task
from core.tracking.register import Level, RegistrationOptions

BONE = "talus"
FRAMES = (0, 4)  # the frames the tasks cover, of the demo's 30
# one short CMA-ES level per frame and no verifying restarts: a quick batch (with the default
# search and the 4-frame walk this test had before, the bones moved tens of mm per frame and
# every frame failed its checks and was retried)
_FAST = RegistrationOptions(bounds=(5.0, 5.0), refine="pattern", levels=(
    Level(1.0, "cmaes", (1.0, 1.0), popsize=10, max_generations=40, tol_x=0.02),))
SETTINGS = TaskSettings(device="cpu", confidence=False, options=(
    ("verify_restarts", 0), ("registration", _FAST), ("first", _FAST)))


@pytest.fixture(scope="module")
def demo(tmp_path_factory, demo_walk_48):
    """A copy of the 30-frame demo walk (the bones move little from frame to frame) whose talus
    has keyframes at frames 1 and 3 (the true poses) only."""
    out = shutil.copytree(demo_walk_48, tmp_path_factory.mktemp("ranges") / "demo")
    truth = np.load(out / "poses" / f"{BONE}.npy")
    with Study.open(out, mode="w") as st:
        trial = st.trial("walk")
        trial.clear_pose(BONE, 0)
        for k in (1, 3):
            trial.record_pose(BONE, k, truth[k])
    return out


def test_keyframe_ranges():
    assert keyframe_ranges([3, 10], 0, 20) == [(3, 0), (3, 9), (10, 19)]
    assert keyframe_ranges([0, 1, 4], 0, 5) == [(0, 0), (1, 3), (4, 4)]
    assert keyframe_ranges([7, 30], 5, 12) == [(7, 5), (7, 11)]  # keyframes outside are ignored
    assert keyframe_ranges([], 2, 6) == [(2, 5)]  # none inside: the whole range, forward
    with pytest.raises(ValueError, match="frames"):
        keyframe_ranges([1], 3, 3)


def test_range_tasks(demo):
    tasks = build_tasks([demo], bones=[BONE], ranges=True, frames=FRAMES)
    assert [t.key for t in tasks] == ["demo/walk/talus:1-0", "demo/walk/talus:1-2", "demo/walk/talus:3-3"]
    assert [t.order for t in tasks] == [[1, 0], [1, 2], [3]]
    assert tasks[0].report_name == "walk.talus.1-0"
    first3 = build_tasks([demo], bones=[BONE], ranges=True, frames=(0, 3))
    assert [t.frames for t in first3] == [(1, 0), (1, 2)]
    # a joint group splits where every bone has a keyframe: talus {1, 3}, calcaneus {0}: nowhere
    joint = build_tasks([demo], bones=[BONE, "calcaneus"], joint=True, ranges=True, frames=FRAMES)
    assert [(t.bones, t.frames) for t in joint] == [((BONE, "calcaneus"), (0, 3))]
    assert joint[0].report_name == "walk.0-3" and joint[0].key == "demo/walk/talus+calcaneus:0-3"
    whole = BatchTask("/s", "walk", (BONE,))
    assert whole.order is None and whole.key == "s/walk/talus" and whole.report_name == "walk.talus"
    with pytest.raises(ValueError, match="spline"):
        run_task(tasks[0], TaskSettings(guess="spline"))


def test_range_task_is_refused_while_another_writer_holds_the_bone(demo, tmp_path, monkeypatch):
    monkeypatch.setattr(batch_journal, "JOURNAL_START_WAIT_S", 0.05)
    folder = shutil.copytree(demo, tmp_path / "held")
    task = build_tasks([folder], bones=[BONE], ranges=True, frames=FRAMES)[1]
    with Study.open(folder, mode="w") as st:
        st.lock_journal("walk", BONE)  # e.g. the window, or talus track
        with pytest.raises(LockedError, match="talus"):
            run_task(task, SETTINGS)
    with Study.open(folder) as st:
        assert not np.isfinite(st.trial("walk").poses(BONE)[2]).any()  # nothing written


def test_range_records_share_the_journal_and_cut_a_torn_tail(demo, tmp_path):
    """Two handles write one bone's journal record by record (as two range tasks do); a record
    torn by a killed writer is cut off before the next append."""
    folder = shutil.copytree(demo, tmp_path / "shared")
    pose = np.load(folder / "poses" / f"{BONE}.npy")
    with Study.open(folder, mode="w") as a, Study.open(folder, mode="w") as b:
        ta, tb = batch_journal.SharedJournals(a).trial("walk"), batch_journal.SharedJournals(b).trial("walk")
        ta.record_pose(BONE, 0, pose[0], score=0.5)
        journal = folder / "results" / "walk" / "poses" / f"{BONE}.jsonl"
        with open(journal, "ab") as fh:
            fh.write(b'{"v":2,"frame":2,"pose":[1.0')  # a writer killed mid-append
        tb.record_pose(BONE, 2, pose[2], score=0.6)
        assert not a.journal_locked("walk", BONE) and not b.journal_locked("walk", BONE)
    with Study.open(folder) as st:
        state = st.trial("walk").results(BONE)
        assert state.torn_bytes == 0 and sorted(state.records) == [0, 1, 2, 3]
        np.testing.assert_allclose(st.trial("walk").poses(BONE)[[0, 2]], pose[[0, 2]])


def test_ranges_on_two_workers_match_a_serial_run_and_resume(demo, tmp_path):
    pytest.importorskip("distributed")
    from core.tracking.batch import run_batch
    from core.tracking.from_study import track_study

    serial_dir = shutil.copytree(demo, tmp_path / "serial")
    batch_dir = shutil.copytree(demo, tmp_path / "batch")
    tasks = build_tasks([batch_dir], bones=[BONE], ranges=True, frames=FRAMES)
    with Study.open(serial_dir, mode="w") as st:  # the reference: talus track over each range
        for t in tasks:
            res, _ = track_study(st, "walk", [BONE], t.order, options=SETTINGS.tracking_options(False),
                                 device="cpu", resume=True)
            assert res.status == "complete"

    events = []
    summary = run_batch(tasks, SETTINGS, workers=2, on_event=events.append)
    assert summary["status"] == "complete" and summary["tasks_complete"] == 3, summary
    rows = {r["key"]: r for r in summary["task_records"]}
    assert sum(r["frames_tracked"] for r in rows.values()) in (4, 5)  # frame 1 by one range or both
    assert {e["kind"] for e in events} == {"start", "frame", "end"}
    with Study.open(serial_dir) as a, Study.open(batch_dir) as b:
        pa, pb = a.trial("walk").poses(BONE), b.trial("walk").poses(BONE)
        assert np.isfinite(pb[:4]).all() and np.isnan(pb[4:]).all()
        np.testing.assert_allclose(pb, pa, rtol=0, atol=1e-9)
        assert sorted(b.trial("walk").results(BONE).keyframes) == [1, 3]  # still the hand-set ones
        for t in tasks:  # each range's report as the trajectory check over the ranges left it
            rep = b.read_report("tracking", t.report_name)
            assert rep["summary"]["status"] == "complete" and rep["trajectory_pass"]["judged"] == 4
            assert rep["summary"]["flagged"] == rows[t.key]["flagged"] == len(rep["flagged"])
    (entry,) = summary["trajectory_pass"]  # run by run_batch once the ranges were done
    assert entry["judged"] == 4 and sorted(entry["reports"]) == sorted(t.report_name for t in tasks)
    assert all("flagged_before_pass" in r for r in rows.values())

    again = run_serial(build_tasks([batch_dir], bones=[BONE], ranges=True, frames=FRAMES), SETTINGS)
    assert again["status"] == "complete" and again["frames_tracked"] == 0
    assert [r["frames_resumed"] for r in again["task_records"]] == [2, 2, 1]
