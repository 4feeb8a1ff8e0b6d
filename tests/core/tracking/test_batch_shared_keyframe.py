"""``talus batch --ranges``: the backward check's outcome at the keyframe two ranges share
(core.tracking.backward_check) does not depend on the order the ranges ran — after the trial's pass
(core.tracking.batch_pass) the frame carries both ranges' flags and notes in frame order and their backward
registrations' evaluations added up, in the journal and both reports, whether or not a range flagged it,
with the trajectory check on or off, and with a range not complete. Synthetic poses (the registration is
replaced): no rendering."""

from __future__ import annotations

import itertools
import shutil
import threading

import numpy as np

from core.study import Study
from core.tracking import batch, trial
from core.tracking.backward_check import FLAG, NOTE
from core.tracking.batch_pass import SHARED_KEYS, pass_messages
from core.tracking.results import FrameResult
from tests.core.tracking.test_flags_post import _track

BONE = "talus"
KEY = 12  # the keyed walk's talus keyframe: ranges 12-0 and 12-29
SETTINGS = batch.TaskSettings(device="cpu", confidence=False)
NO_TRAJECTORY = batch.TaskSettings(device="cpu", confidence=False, options=(("trajectory_limit", None),))


def _turned(pose, deg):
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    out = np.array(pose, dtype=float)
    out[:3, :3] = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]) @ out[:3, :3]
    return out


def _step(off_from):
    """The frame step: a smooth walk, the keyframe's backward registration 2 deg off when it is predicted
    from the frames after it (``off_from`` "after") or before it ("before"; else neither)."""
    P = _track(n=30)

    def step(run, f, imgs, fr, todo, state, skip):
        hist = [g for g, *_ in state[BONE].history] if BONE in state else []
        backward = (f == KEY and hist and off_from in ("after", "before")
                    and all((g > KEY) == (off_from == "after") for g in hist))
        return {0: FrameResult(BONE, f, _turned(P[f], 2.0) if backward else P[f], 0.8, 10, 0.0, True)}

    return step


def _state(folder, tasks):
    """Every journaled frame (pose and tracking fields) and every range report's frames and pass sections:
    what must not depend on the order the ranges ran."""
    with Study.open(folder) as st:
        recs = st.trial("walk").results(BONE).records
        journal = {int(f): (np.asarray(r.pose).round(12).tolist(), r.tracking) for f, r in recs.items()
                   if r.tracking}
        reports = {t.report_name: {k: v for k, v in st.read_report("tracking", t.report_name).items()
                                   if k in ("frames_done", "flagged", "trajectory_pass", "shared_keyframes")}
                   for t in tasks}
    return journal, reports


def _run(keyed, tmp_path, monkeypatch, name, reverse, off_from, settings=SETTINGS):
    """The keyed walk copied to ``name``, its two talus ranges run serially (``reverse``: the forward
    range first) with :func:`_step`: (the keyframe's journal record, the two reports' keyframe entries, the
    summary, :func:`_state`)."""
    monkeypatch.setattr(trial, "track_frame", _step(off_from))
    folder = shutil.copytree(keyed, tmp_path / name / "demo")  # the same study name: the same messages
    tasks = batch.build_tasks([folder], bones=[BONE], ranges=True)
    s = batch.run_serial(tasks[::-1] if reverse else tasks, settings)
    assert s["status"] == "complete"
    state = _state(folder, tasks)
    rec = state[0][KEY][1]
    entries = [[d for d in r["frames_done"] if d["frame"] == KEY] for r in state[1].values()]
    return rec, entries, s, state


def test_the_shared_keyframes_backward_flag_does_not_depend_on_the_order_the_ranges_ran(
        keyed, tmp_path, monkeypatch):
    for off_from in ("after", "before"):  # the forward range flags it, then the backward one
        runs = [_run(keyed, tmp_path, monkeypatch, f"{off_from}{int(rev)}", rev, off_from)
                for rev in (False, True)]
        (_, _, s0, state0), (_, _, s1, state1) = runs
        assert state0 == state1 and len(state0[0]) == 30  # every frame journaled and reported alike
        for rec, entries, *_ in runs:
            flags = [x for x in rec["flags"] if x.startswith(FLAG)]
            notes = [x for x in rec["notes"] if x.startswith(NOTE)]
            assert len(flags) == 1 and len(notes) == 1  # one range's flag, the other's note
            for (d,) in entries:  # both range reports say what the journal says
                assert (d["flags"], d["notes"], d["timing"]) == (rec["flags"], rec["notes"], rec["timing"])
            # both ranges' backward registrations (10 evaluations each, the stub's)
            assert rec["timing"]["backward_evaluations"] == 20 and rec["timing"]["backward_ranges"] == 2
        for s in (s0, s1):
            # the range that ran first had its flag or note overwritten in the journal; the pass restored it
            (entry,) = s["trajectory_pass"]
            assert entry["changed"] == [[BONE, KEY]] and entry["review_flagged"] == {BONE: 1}
            assert entry["shared_keyframes"] == [[BONE, KEY]]
            (line,) = [m for m in pass_messages(entry) if f"frame {KEY}:" in m]
            assert FLAG in line and "off the trajectory" not in line  # it never was
            assert entry["changes"][0]["was_off_trajectory"] is False


def test_no_range_flagging_the_shared_keyframe_gets_both_ranges_notes(keyed, tmp_path, monkeypatch):
    runs = [_run(keyed, tmp_path, monkeypatch, f"none{int(rev)}", rev, "neither") for rev in (False, True)]
    assert runs[0][3] == runs[1][3]  # journal and reports, whichever range ran last
    for rec, entries, s, _ in runs:
        assert not [x for x in rec["flags"] if x.startswith(FLAG)]
        # the backward range's note (predicted from frames 11 and 10) first, then the forward range's
        back, fwd = [x for x in rec["notes"] if x.startswith(NOTE)]
        assert "frames 11 and 10;" in back and "frames 13 and 14;" in fwd
        assert [d["notes"] for (d,) in entries] == [rec["notes"]] * 2
        (entry,) = s["trajectory_pass"]
        assert entry["changed"] == [] and entry["shared_keyframes"] == [[BONE, KEY]]  # a note: not named
        assert entry["journaled_again"] == [[BONE, KEY]]
        assert not [m for m in pass_messages(entry) if f"frame {KEY}:" in m]
    # a pass run again changes nothing (the reports' sums are not added again)
    folder = tmp_path / "none1" / "demo"
    tasks = batch.build_tasks([folder], bones=[BONE], ranges=True)
    before = _state(folder, tasks)
    (again,) = batch.trajectory_pass(tasks, [{"key": t.key, "status": "complete"} for t in tasks], SETTINGS)
    assert again["journaled_again"] == [] and again["reports"] == [] and _state(folder, tasks) == before


def test_the_merge_runs_with_the_trajectory_check_off(keyed, tmp_path, monkeypatch):
    runs = [_run(keyed, tmp_path, monkeypatch, f"off{int(rev)}", rev, "after", NO_TRAJECTORY)
            for rev in (False, True)]
    assert runs[0][3] == runs[1][3]
    for rec, entries, s, (_, reports) in runs:
        assert len([x for x in rec["flags"] if x.startswith(FLAG)]) == 1
        assert len([x for x in rec["notes"] if x.startswith(NOTE)]) == 1
        assert [d["flags"] for (d,) in entries] == [rec["flags"]] * 2
        (entry,) = s["trajectory_pass"]
        assert entry["off"] and entry["judged"] == 0 and entry["changed"] == [[BONE, KEY]]
        assert entry["shared_keyframes"] == [[BONE, KEY]] and "review_flagged" not in entry
        lines = pass_messages(entry)
        assert lines[0] == ("demo/walk/talus: trajectory check off (the keyframe they share given both "
                            "ranges' backward checks)")
        assert lines[1].startswith(f"demo/walk/talus: talus frame {KEY}: {FLAG}") and len(lines) == 2
        # no trajectory section: the reports say what was merged
        for rep in reports.values():
            assert "trajectory_pass" not in rep
            assert rep["shared_keyframes"]["shared_keyframes"] == [[BONE, KEY]]
            assert rep["shared_keyframes"]["judged"] == 0 and rep["shared_keyframes"]["limit"] is None
        rec_counts = {r["key"]: (r["flagged_before_pass"], r["flagged"]) for r in s["task_records"]}
        assert sorted(rec_counts.values()) == [(0, 1), (1, 1)]  # the range that lost its flag gets it back


def test_the_merge_runs_with_a_range_not_complete(keyed, tmp_path, monkeypatch):
    """A second keyframe at 20 makes three ranges, 12-0, 12-19 and 20-29; 20-29 cancelled after frame 22
    leaves the group not judged. The two ranges sharing 12, run in both orders (12-19 flagging it), give the
    same journal and reports: the flag and the other range's note."""
    monkeypatch.setattr(trial, "track_frame", _step("after"))
    states = []
    for rev in (False, True):
        folder = shutil.copytree(keyed, tmp_path / f"part{int(rev)}" / "demo")
        with Study.open(folder, mode="w") as st:
            st.trial("walk").record_pose(BONE, 20, _track(n=30)[20])
        tasks = batch.build_tasks([folder], bones=[BONE], ranges=True)
        assert [t.frames for t in tasks] == [(12, 0), (12, 19), (20, 29)]
        back, fwd, last = tasks
        done: list[int] = []
        records = {last.key: batch.run_task(last, SETTINGS, progress=lambda e, done=done: done.append(
            e.get("frame")), cancel=lambda done=done: 22 in done)}
        for t in ([fwd, back] if rev else [back, fwd]):
            records[t.key] = batch.run_task(t, SETTINGS)
        assert records[last.key]["status"] == "cancelled" and records[back.key]["status"] == "complete"
        (entry,) = batch.trajectory_pass(tasks, [records[t.key] for t in tasks], SETTINGS)
        assert "1 of 3 ranges not complete" in entry["skipped"] and entry["shared_keyframes"] == [[BONE, KEY]]
        assert entry["changed"] == [[BONE, KEY]]  # the flag or the note the range run last overwrote
        journal, reports = _state(folder, tasks)
        rec = journal[KEY][1]
        assert len([x for x in rec["flags"] if x.startswith(FLAG)]) == 1
        assert len([x for x in rec["notes"] if x.startswith(NOTE)]) == 1
        assert rec["timing"]["backward_ranges"] == 2
        for name in (back.report_name, fwd.report_name):
            (d,) = [d for d in reports[name]["frames_done"] if d["frame"] == KEY]
            assert (d["flags"], d["notes"]) == (rec["flags"], rec["notes"])
            assert reports[name]["shared_keyframes"]["shared_keyframes"] == [[BONE, KEY]]
        assert "shared_keyframes" not in reports[last.report_name]  # not one of the ranges sharing 12
        lines = pass_messages(entry)
        assert "did not run (1 of 3 ranges not complete" in lines[0]
        assert "the keyframe they share given both ranges' backward checks" in lines[0]
        assert lines[1].startswith(f"demo/walk/talus: talus frame {KEY}: {FLAG}") and len(lines) == 2
        states.append((journal, reports))
    assert states[0] == states[1]


def test_merge_of_synthetic_records_ignores_task_order_and_an_unreadable_report():
    # no study: the journal's record and the two range reports as dicts, the reports in both orders
    from types import SimpleNamespace

    from core.tracking.batch_pass import _shared_first_frames

    back = SimpleNamespace(order=[12, 11, 10], report_name="back", key="k:12-10")
    fwd = SimpleNamespace(order=[12, 13, 14], report_name="fwd", key="k:12-14")
    flag, note = f"{FLAG} (fwd)", f"{NOTE} (back)"
    t_back = {"backward_evaluations": 7, "backward_s": 0.5}
    t_fwd = {"backward_evaluations": 9, "backward_s": 0.25}
    reports = {"back": {"frames_done": [{"bone": BONE, "frame": 12, "flags": [], "notes": [note],
                                         "timing": t_back}]},
               "fwd": {"flagged": [{"bone": BONE, "frame": 12, "flags": [flag], "notes": [],
                                    "timing": t_fwd}]}}
    P = np.eye(4)

    def read(kind, name):
        return reports[name]

    for journal in (FrameResult(BONE, 12, P, 0.8, 10, 0.0, True, notes=("other", note), timing=dict(t_back)),
                    FrameResult(BONE, 12, P, 0.8, 10, 0.0, True, (flag,), timing=dict(t_fwd))):
        for tasks in ([back, fwd], [fwd, back]):
            merged, joined = _shared_first_frames({(BONE, 12): journal}, tasks, [BONE], read)
            got = merged[(BONE, 12)]
            assert joined == [(BONE, 12)] and got.flags == (flag,) and note in got.notes
            # the reports' entries carry no time_s: the journal's registration alone, named as shared
            assert got.timing == {"backward_evaluations": 16, "backward_s": 0.75, "backward_ranges": 2,
                                  "shared_ranges": 2, "shared_registrations": 1}
            assert (got.time_s, got.evaluations) == (0.0, 10)
    # the flagging range's report unreadable: the journal's record stays, nothing invented
    journal = FrameResult(BONE, 12, P, 0.8, 10, 0.0, True, notes=(note,))

    def unreadable(kind, name):
        if name == "fwd":
            raise OSError("removed")
        return reports[name]

    merged, joined = _shared_first_frames({(BONE, 12): journal}, [back, fwd], [BONE], unreadable)
    assert merged[(BONE, 12)] is journal and joined == []
    # reports written by an earlier merge hold the sum: taken as it is
    summed = {"backward_evaluations": 16, "backward_s": 0.75, "backward_ranges": 2}
    for r in reports.values():
        for d in r.get("frames_done", []) + r.get("flagged", []):
            d["timing"] = dict(summed)
    merged, _ = _shared_first_frames({(BONE, 12): journal}, [back, fwd], [BONE], read)
    assert {k: v for k, v in merged[(BONE, 12)].timing.items() if k.startswith("backward_")} == summed


def _timed_step(barrier=None):
    """The frame step of a smooth walk, each registration its own time and evaluations (the n-th call: n s,
    100 + n); ``barrier``: a range's first frame waits there for the other's (both register the keyframe
    before either journals it, as ranges run side by side on two workers)."""
    P, calls = _track(n=30), itertools.count(1)

    def step(run, f, imgs, fr, todo, state, skip):
        n = next(calls)
        if barrier is not None and f == KEY and not state[BONE].history:
            barrier.wait()
        return {0: FrameResult(BONE, f, P[f], 0.8, 100 + n, float(n), True)}

    return step


def _keyframe_work(folder, tasks):
    """The keyframe's (time_s, evaluations, shared timing keys) in the journal and each range report, and
    each report's summary evaluations against its frames' sum."""
    with Study.open(folder) as st:
        t = st.trial("walk").results(BONE).records[KEY].tracking
        out = [(t["time_s"], t["evaluations"], {k: t["timing"].get(k) for k in SHARED_KEYS})]
        for task in tasks:
            rep = st.read_report("tracking", task.report_name)
            (d,) = [d for d in rep["frames_done"] if d["frame"] == KEY]
            out.append((d["time_s"], d["evaluations"], {k: d["timing"].get(k) for k in SHARED_KEYS}))
            assert rep["summary"]["evaluations"] == sum(e["evaluations"] for e in rep["frames_done"])
    return out


def test_the_shared_keyframes_registration_is_named_and_counted_once(keyed, tmp_path, monkeypatch):
    """Run one after the other, the second range takes the keyframe back from the journal: its report gave
    the first range's registration as its own. After the pass both reports and the journal give that one
    registration, named (shared by 2 ranges, 1 registration), whichever range ran first."""
    for rev in (False, True):
        monkeypatch.setattr(trial, "track_frame", _timed_step())
        folder = shutil.copytree(keyed, tmp_path / f"serial{int(rev)}" / "demo")
        tasks = batch.build_tasks([folder], bones=[BONE], ranges=True)
        batch.run_serial(tasks[::-1] if rev else tasks, SETTINGS)
        first = 1.0  # the keyframe is the first range's first call, whichever range that is
        work = _keyframe_work(folder, tasks)
        assert work == [(first, 101, {"shared_ranges": 2, "shared_registrations": 1})] * 3
        # a pass run again changes nothing
        (again,) = batch.trajectory_pass(tasks, [{"key": t.key, "status": "complete"} for t in tasks],
                                         SETTINGS)
        assert again["journaled_again"] == [] and _keyframe_work(folder, tasks) == work


def test_ranges_run_side_by_side_count_both_registrations(keyed, tmp_path, monkeypatch):
    """Run side by side (threads here, workers in a batch), both ranges register the keyframe: after the
    pass its time and evaluations are both registrations' (2 registrations), in both reports (their summaries
    moved with them) and the journal."""
    monkeypatch.setattr(trial, "track_frame", _timed_step(threading.Barrier(2, timeout=60)))
    # (the threads stand for a batch's worker processes, each with its own device lock: no rendering here)
    monkeypatch.setattr(trial, "device_lock", lambda device: threading.RLock())
    folder = shutil.copytree(keyed, tmp_path / "parallel" / "demo")
    tasks = batch.build_tasks([folder], bones=[BONE], ranges=True)
    records = {}
    threads = [threading.Thread(target=lambda t=t: records.__setitem__(t.key, batch.run_task(t, SETTINGS)))
               for t in tasks]
    for th in threads:
        th.start()
    for th in threads:
        th.join()
    assert [records[t.key]["frames_resumed"] for t in tasks] == [0, 0]  # both registered it
    (entry,) = batch.trajectory_pass(tasks, [records[t.key] for t in tasks], SETTINGS)
    assert entry["shared_keyframes"] == [[BONE, KEY]]
    work = _keyframe_work(folder, tasks)
    assert work == [(1.0 + 2.0, 101 + 102, {"shared_ranges": 2, "shared_registrations": 2})] * 3
    (again,) = batch.trajectory_pass(tasks, [records[t.key] for t in tasks], SETTINGS)
    assert again["journaled_again"] == [] and _keyframe_work(folder, tasks) == work
