"""``talus batch --ranges``: after the trajectory check over a trial's ranges (core.tracking.batch_pass)
the journal, every range report and the summary's task records give the flags that pass left, and
its entry words what it judged and changed. Synthetic poses (the registration is replaced): no
rendering."""

from __future__ import annotations

import shutil
from functools import partial

import numpy as np

from core.study import Study
from core.tracking import batch, flags_post, trial
from core.tracking.batch_pass import pass_messages
from core.tracking.flags_post import FLAG
from core.tracking.results import FrameResult
from tests.core.tracking.test_flags_post import _track

BONE = "talus"
SETTINGS = batch.TaskSettings(device="cpu", confidence=False)  # the registration itself is replaced


def _journal_flags(folder) -> dict[int, list[str]]:
    with Study.open(folder) as st:
        recs = st.trial("walk").results(BONE).records
    return {int(f): list(r.tracking["flags"]) for f, r in recs.items() if r.tracking}


def _batch(keyed, tmp_path, monkeypatch, step=None):
    """The keyed walk copied and its talus's ranges 12-0 and 12-29 as tasks, for ``run_serial``, the
    registration replaced by ``step`` (default: frame 10 0.2 deg off a smooth walk — the range
    12-0, run first, judges it without 13-29 and does not flag it; judged with the whole trial it
    is off the trajectory): (folder, tasks)."""
    P = _track(n=30, off=(10, 0.0, 0.2))
    # the check with the window cut at a trial's ends (ends=False): with flags_ends the range 12-0 fits frame
    # 10, near its end, through 8 frames and flags it itself
    monkeypatch.setattr(flags_post, "trajectory_review", partial(flags_post.trajectory_review, ends=False))
    monkeypatch.setattr(trial, "track_frame", step or (lambda run, f, imgs, fr, todo, state, skip: {
        0: FrameResult(BONE, f, P[f], 0.8, 10, 0.0, True)}))
    folder = shutil.copytree(keyed, tmp_path / "demo")
    return folder, batch.build_tasks([folder], bones=[BONE], ranges=True)


def test_range_reports_and_records_give_the_flags_after_the_trials_pass(keyed, tmp_path, monkeypatch):
    # frame 10, 0.2 deg off: the range 12-0, run first, judges it without 13-29 and does not flag
    # it; judged with the whole trial it is off the trajectory
    folder, tasks = _batch(keyed, tmp_path, monkeypatch)
    s = batch.run_serial(tasks, SETTINGS)
    assert s["status"] == "complete"
    (entry,) = s["trajectory_pass"]
    a, b = "demo/walk/talus:12-0", "demo/walk/talus:12-29"
    assert entry["key"] == "demo/walk/talus" and entry["ranges"] == [a, b]
    assert entry["judged"] == 30 and entry["flagged"] == 1 and entry["review_flagged"] == {BONE: 1}
    assert entry["changed"] == [[BONE, 10]]
    (change,) = entry["changes"]
    assert change["frame"] == 10 and change["flags"][0].startswith(FLAG)
    assert change["was_flagged"] is False and change["notes"] == []  # its range's check had not flagged it
    assert entry["tasks_flagged"] == {a: 1, b: 0}
    assert entry["reports"] == ["walk.talus.12-0", "walk.talus.12-29"] and entry["reports_unreadable"] == []
    # the records: the count after the pass, and the task's own
    rec = {r["key"]: r for r in s["task_records"]}
    assert (rec[a]["flagged_before_pass"], rec[a]["flagged"]) == (0, 1)
    assert (rec[b]["flagged_before_pass"], rec[b]["flagged"]) == (0, 0)
    # every range report agrees with the journal, frame by frame
    journal = _journal_flags(folder)
    assert sorted(f for f, fl in journal.items() if fl) == [10]
    with Study.open(folder) as st:
        for t, changed in zip(tasks, ([[BONE, 10]], []), strict=True):
            rep = st.read_report("tracking", t.report_name)
            assert sorted(d["frame"] for d in rep["frames_done"]) == sorted(t.order)
            assert all(d["flags"] == journal[d["frame"]] for d in rep["frames_done"])
            assert [d["frame"] for d in rep["flagged"]] == [f for f in t.order if journal[f]]
            assert rep["summary"]["flagged"] == len(rep["flagged"]) and rep["summary"]["status"] == "complete"
            assert rep["trajectory_pass"]["changed"] == changed and rep["trajectory_pass"]["judged"] == 30
            assert rep["trajectory_pass"]["ranges"] == ["walk.talus.12-0", "walk.talus.12-29"]
            assert rep["options"]["mode"] == "sequential" and rep["trial"] == "walk"  # the rest as written
    lines = pass_messages(entry)
    assert lines[0] == ("demo/walk/talus: 1 flagged for review after the trajectory check over its 2 ranges "
                        "together (30 bone-frames judged, 1 off the trajectory, 1 changed by the check)")
    assert lines[1].startswith("demo/walk/talus: talus frame 10: off the trajectory") and len(lines) == 2
    # once more: no flag changes; only the report whose range the first pass changed is written
    # again (its trajectory_pass section tells the latest pass)
    records = [{"key": t.key, "status": "complete"} for t in tasks]
    (again,) = batch.trajectory_pass(tasks, records, SETTINGS)
    assert again["changed"] == [] and again["reports"] == ["walk.talus.12-0"]
    assert _journal_flags(folder) == journal
    with Study.open(folder) as st:
        rep = st.read_report("tracking", "walk.talus.12-0")
    assert rep["trajectory_pass"]["changed"] == [] and [d["frame"] for d in rep["flagged"]] == [10]


def test_a_trial_whose_ranges_are_not_all_complete_is_not_judged_and_says_so():
    tasks = [batch.BatchTask("/s/demo", "walk", (BONE,), r) for r in ((12, 0), (12, 29))]
    records = [{"key": tasks[0].key, "status": "complete"}, {"key": tasks[1].key, "status": "cancelled"}]
    # not judged; the keyframe both ranges share is merged all the same (here no study to open: said)
    (entry,) = batch.trajectory_pass(tasks, records, SETTINGS)
    assert entry["key"] == "demo/walk/talus"
    assert "1 of 2 ranges not complete (demo/walk/talus:12-29)" in entry["skipped"]
    assert "tasks_flagged" not in entry and "error" not in entry and entry["shared_error"]
    line, merge = pass_messages(entry)
    assert "did not run" in line and "each range keeps its own flags" in line
    assert "the backward checks of the keyframe its ranges share not merged" in merge
    # ranges that share no first frame: nothing opened
    apart = [batch.BatchTask("/s/demo", "walk", (BONE,), r) for r in ((12, 0), (13, 29))]
    (entry,) = batch.trajectory_pass(apart, [{"key": apart[0].key, "status": "complete"}], SETTINGS)
    assert "skipped" in entry and "shared_error" not in entry
    (line,) = pass_messages(entry)
    assert "did not run" in line and "each range keeps its own flags" in line
    assert batch.trajectory_pass([batch.BatchTask("/s/demo", "walk", (BONE,))], records, SETTINGS) == []
    # the records of ranges not judged keep their own counts
    from core.tracking.batch_pass import final_records

    assert final_records([dict(records[0], flagged=2)], [entry]) == [dict(records[0], flagged=2)]


def test_pass_messages_name_ten_changed_frames_and_count_the_rest():
    changes = [{"bone": "calcaneus" if f % 2 else BONE, "frame": f,
                "flags": [f"{FLAG} (3.1 x the median residual)"]} for f in range(11)]
    changes += [{"bone": BONE, "frame": 20, "flags": []},
                {"bone": BONE, "frame": 21, "flags": ["score drop (0.4 of the median)"]}]
    entry = {"key": "demo/walk/talus+calcaneus", "ranges": ["a", "b", "c"], "judged": 90, "flagged": 11,
             "review_flagged": {BONE: 7, "calcaneus": 5}, "changes": changes}
    lines = pass_messages(entry)
    assert lines[0] == ("demo/walk/talus+calcaneus: 12 flagged for review (talus 7, calcaneus 5) after the "
                        "trajectory check over its 3 ranges together (90 bone-frames judged, 11 off the "
                        "trajectory, 13 changed by the check)")
    key = "demo/walk/talus+calcaneus"
    assert len(lines) == 12 and lines[1] == f"{key}: talus frame 0: {FLAG} (3.1 x the median residual)"
    assert lines[2].startswith("demo/walk/talus+calcaneus: calcaneus frame 1: ")
    assert lines[-1] == (f"{key}: ... and 3 more frames changed by the check: the review panel lists "
                         "the flagged ones")
    more = pass_messages(entry, limit=20)
    assert more[-2].endswith("talus frame 20: no longer flagged")
    assert more[-1].endswith("talus frame 21: no longer off the trajectory (still flagged: score drop "
                             "(0.4 of the median))")


def test_pass_messages_say_range_for_one_range():
    """One range: 'its 1 range', not 'its 1 ranges'; no 'together'; the range keeps its flags."""
    assert pass_messages({"key": "k", "ranges": ["a"], "error": "LockedError: held"}) == [
        "k: the trajectory check over its 1 range failed (LockedError: held); the range keeps its own flags"]
    assert pass_messages({"key": "k", "ranges": ["a"], "skipped": "not complete"}) == [
        "k: the trajectory check over its 1 range did not run (not complete); the range keeps its own flags"]
    (line,) = pass_messages({"key": "k", "ranges": ["a"], "error": "E", "journaled": [["talus", 3]],
                             "changed_total": 2})
    assert "over its 1 range failed (E) after journaling 1 of 2 changed frames (talus frame 3)" in line
    assert line.endswith("the range's reports and records their own")
    one = {"key": "k", "ranges": ["a"], "judged": 30, "flagged": 1, "review_flagged": {"talus": 1}}
    assert pass_messages(one)[0] == (
        "k: 1 flagged for review after the trajectory check over its 1 range (30 bone-frames judged, 1 off "
        "the trajectory, 0 changed by the check)")


def test_a_flagged_frame_without_a_pose_stays_counted_after_the_pass(keyed, tmp_path, monkeypatch):
    # frame 5 missing in a view: flagged, no pose, so never journaled; the range's report and
    # record counted it before the pass and must still after it (frame 10 flagged by the pass)
    P = _track(n=30, off=(10, 0.0, 0.2))
    missing = ("frame missing in view 1",)

    def step(run, f, imgs, fr, todo, state, skip):
        if f == 5:
            return {0: FrameResult(BONE, f, None, np.nan, 0, 0.0, False, missing)}
        return {0: FrameResult(BONE, f, P[f], 0.8, 10, 0.0, True)}

    folder, tasks = _batch(keyed, tmp_path, monkeypatch, step)
    s = batch.run_serial(tasks, SETTINGS)
    (entry,) = s["trajectory_pass"]
    a, b = "demo/walk/talus:12-0", "demo/walk/talus:12-29"
    rec = {r["key"]: r for r in s["task_records"]}
    assert rec[a]["flagged_before_pass"] == 1
    with Study.open(folder) as st:
        rep = st.read_report("tracking", tasks[0].report_name)
    assert sorted(d["frame"] for d in rep["flagged"]) == [5, 10] and rep["summary"]["flagged"] == 2
    assert rec[a]["flagged"] == rep["summary"]["flagged"] == entry["tasks_flagged"][a]
    assert entry["tasks_flagged"][b] == rec[b]["flagged"] == 0
    assert entry["review_flagged"] == {BONE: 2}


def test_a_report_that_cannot_be_written_leaves_the_pass_told(keyed, tmp_path, monkeypatch):
    # the journal takes the pass's flags before the reports are rewritten: a report whose write
    # fails (its lock held, the disk full) is named, and the entry still says what the journal holds
    from core.study.study_reports import StudyReports

    folder, tasks = _batch(keyed, tmp_path, monkeypatch)
    real = StudyReports.write_report

    def write(self, kind, name, data):
        if "trajectory_pass" in data and name == "walk.talus.12-0":
            raise TimeoutError("report lock held")
        return real(self, kind, name, data)

    monkeypatch.setattr(StudyReports, "write_report", write)
    s = batch.run_serial(tasks, SETTINGS)
    (entry,) = s["trajectory_pass"]
    assert "error" not in entry and entry["changed"] == [[BONE, 10]]
    assert sorted(f for f, fl in _journal_flags(folder).items() if fl) == [10]
    assert entry["reports"] == ["walk.talus.12-29"]
    assert entry["reports_unwritten"] == ["walk.talus.12-0: TimeoutError: report lock held"]
    rec = {r["key"]: r for r in s["task_records"]}
    assert rec["demo/walk/talus:12-0"]["flagged"] == 1  # as the journal holds it
    lines = pass_messages(entry)
    assert "each range keeps its own flags" not in lines[0]
    assert lines[-1] == ("demo/walk/talus: 1 range report not rewritten with the flags after the check "
                         "(walk.talus.12-0: TimeoutError: report lock held)")


def test_a_pass_cut_off_while_journaling_says_which_frames_it_journaled(keyed, tmp_path, monkeypatch):
    # the second of two changed frames cannot be journaled (another writer took the bone): the
    # entry is an error that names the frame journaled before, which carries the pass's flag
    import core.tracking.flags_post as fp
    from core.tracking.batch_journal import _SharedTrial

    truth = np.load(keyed / "poses" / f"{BONE}.npy")
    flagged = (f"{FLAG} (test)",)
    changes = [FrameResult(BONE, f, truth[f], 0.8, 10, 0.0, True, flagged) for f in (3, 4)]
    monkeypatch.setattr(fp, "apply_trajectory_flags", lambda res, centers, **kw: (res, changes))
    real, calls = _SharedTrial.record_pose, []

    def record(self, bone, frame, pose, **kw):
        calls.append(frame)
        if len(calls) > 1:
            raise TimeoutError("bone held by the window")
        return real(self, bone, frame, pose, **kw)

    monkeypatch.setattr(_SharedTrial, "record_pose", record)
    folder = shutil.copytree(keyed, tmp_path / "demo")
    tasks = batch.build_tasks([folder], bones=[BONE], ranges=True)
    (entry,) = batch.trajectory_pass(tasks, [{"key": t.key, "status": "complete"} for t in tasks], SETTINGS)
    assert entry["error"] == "TimeoutError: bone held by the window"
    assert entry["journaled"] == [[BONE, 3]]
    assert _journal_flags(folder)[3] == list(flagged)
    (line,) = pass_messages(entry)
    assert line == ("demo/walk/talus: the trajectory check over its 2 ranges failed (TimeoutError: bone held "
                    "by the window) after journaling 1 of 2 changed frames (talus frame 3): those carry "
                    "its flags, the ranges' reports and records their own")


def _ranges_done(keyed, tmp_path, monkeypatch):
    """The keyed walk's talus ranges tracked (frame 10 off the trajectory), the pass not yet run:
    (folder, tasks, records)."""
    folder, tasks = _batch(keyed, tmp_path, monkeypatch)
    return folder, tasks, [batch.run_task(t, SETTINGS) for t in tasks]


def test_a_hand_fix_cannot_land_between_the_pass_reading_and_writing_the_journal(keyed, tmp_path,
                                                                                 monkeypatch):
    """While the pass judges (between its read of the journal and its write of the changed flags) it
    holds the bone's journal lock: a hand fix of frame 10 from another study handle, as the window
    records one, is refused then, and recorded after the pass it stays the frame's pose."""
    import core.tracking.flags_post as fp
    from core.io.atomic import LockedError

    folder, tasks, records = _ranges_done(keyed, tmp_path, monkeypatch)
    truth = np.load(keyed / "poses" / f"{BONE}.npy")
    real, tried = fp.apply_trajectory_flags, []

    def judge(*a, **kw):  # between the read and the write: a hand fix tries to land
        with Study.open(folder, mode="w") as other:
            try:
                other.trial("walk").record_pose(BONE, 10, truth[10])
            except LockedError as exc:
                tried.append(exc)
        return real(*a, **kw)

    monkeypatch.setattr(fp, "apply_trajectory_flags", judge)
    (entry,) = batch.trajectory_pass(tasks, records, SETTINGS)
    assert len(tried) == 1 and "talus" in str(tried[0])  # refused: the pass held the bone
    assert entry["changed"] == [[BONE, 10]] and "error" not in entry
    with Study.open(folder, mode="w") as st:  # the fix, after the pass: the frame's pose
        st.trial("walk").record_pose(BONE, 10, truth[10])
    with Study.open(folder) as st:
        rec = st.trial("walk").results(BONE).records[10]
    assert rec.kind == "hand" and np.array_equal(rec.pose, truth[10])


def test_the_pass_waits_for_a_writer_and_reads_its_hand_fix(keyed, tmp_path, monkeypatch):
    """A writer holds the talus's journal lock (appending a hand fix of frame 10) when the pass starts:
    the pass waits for it, then reads the fix — a hand-set pose, not judged, not journaled again —
    so the fix is not overtaken by the tracked pose with the off-the-trajectory flag."""
    import threading
    import time

    from core.io.atomic import FileLock
    from core.study.results import append_pose

    folder, tasks, records = _ranges_done(keyed, tmp_path, monkeypatch)
    truth = np.load(keyed / "poses" / f"{BONE}.npy")
    poses = folder / "results" / "walk" / "poses"
    lock = FileLock(poses / f".{BONE}.lock", purpose="the test's hand fix").acquire()
    got = []
    try:
        th = threading.Thread(target=lambda: got.append(batch.trajectory_pass(tasks, records, SETTINGS)))
        th.start()
        time.sleep(1.0)
        assert th.is_alive() and not got  # waiting for the lock (up to JOURNAL_START_WAIT_S)
        append_pose(poses / f"{BONE}.jsonl", 10, truth[10])  # the hand fix, under the lock
    finally:
        lock.release()
    th.join(timeout=60)
    (entry,) = got[0]
    assert "error" not in entry, entry
    assert entry["changed"] == [] and entry["judged"] == 29  # frame 10 is a hand-set pose now
    with Study.open(folder) as st:
        rec = st.trial("walk").results(BONE).records[10]
    assert rec.kind == "hand" and np.array_equal(rec.pose, truth[10])
