"""``talus batch --ranges``: the backward check's outcome at the keyframe two ranges share
(core.tracking.backward_check) does not depend on the order the ranges ran — after the trial's pass
(core.tracking.batch_pass) it is flagged when either range flagged it, with each range's flag and
note. Synthetic poses (the registration is replaced): no rendering."""

from __future__ import annotations

import shutil

import numpy as np

from core.study import Study
from core.tracking import batch, trial
from core.tracking.backward_check import FLAG, NOTE
from core.tracking.batch_pass import pass_messages
from core.tracking.results import FrameResult
from tests.core.tracking.test_flags_post import _track

BONE = "talus"
KEY = 12  # the keyed walk's talus keyframe: ranges 12-0 and 12-29
SETTINGS = batch.TaskSettings(device="cpu", confidence=False)


def _turned(pose, deg):
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    out = np.array(pose, dtype=float)
    out[:3, :3] = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]) @ out[:3, :3]
    return out


def _run(keyed, tmp_path, monkeypatch, name, reverse, off_from):
    """The keyed walk copied to ``name``, its two talus ranges run serially (``reverse``: the forward
    range first), the keyframe's backward registration 2 deg off when it is predicted from the frames
    after it (``off_from`` "after") or before it ("before"; else neither), the registration otherwise
    on a smooth walk: (the keyframe's journal record, the two reports' keyframe entries, the summary,
    every journaled frame's flags and notes)."""
    P = _track(n=30)

    def step(run, f, imgs, fr, todo, state, skip):
        hist = [g for g, *_ in state[BONE].history] if BONE in state else []
        backward = (f == KEY and hist and off_from in ("after", "before")
                    and all((g > KEY) == (off_from == "after") for g in hist))
        return {0: FrameResult(BONE, f, _turned(P[f], 2.0) if backward else P[f], 0.8, 10, 0.0, True)}

    monkeypatch.setattr(trial, "track_frame", step)
    folder = shutil.copytree(keyed, tmp_path / name)
    tasks = batch.build_tasks([folder], bones=[BONE], ranges=True)
    s = batch.run_serial(tasks[::-1] if reverse else tasks, SETTINGS)
    assert s["status"] == "complete"
    with Study.open(folder) as st:
        recs = st.trial("walk").results(BONE).records
        rec = recs[KEY].tracking
        every = {int(f): (r.tracking["flags"], r.tracking["notes"]) for f, r in recs.items() if r.tracking}
        reps = [st.read_report("tracking", t.report_name) for t in tasks]
    entries = [[d for d in r["frames_done"] if d["frame"] == KEY] for r in reps]
    return rec, entries, s, every


def test_the_shared_keyframes_backward_flag_does_not_depend_on_the_order_the_ranges_ran(
        keyed, tmp_path, monkeypatch):
    for off_from in ("after", "before"):  # the forward range flags it, then the backward one
        runs = [_run(keyed, tmp_path, monkeypatch, f"{off_from}{int(rev)}", rev, off_from)
                for rev in (False, True)]
        (rec0, ent0, s0, all0), (rec1, ent1, s1, all1) = runs
        assert all0 == all1 and len(all0) == 30  # every frame's flags and notes, not only the keyframe's
        for rec, entries, *_ in runs:
            flags = [x for x in rec["flags"] if x.startswith(FLAG)]
            notes = [x for x in rec["notes"] if x.startswith(NOTE)]
            assert len(flags) == 1 and len(notes) == 1  # one range's flag, the other's note
            for (d,) in entries:  # both range reports say what the journal says
                assert d["flags"] == rec["flags"] and d["notes"] == rec["notes"]
        assert (rec0["flags"], rec0["notes"]) == (rec1["flags"], rec1["notes"])
        assert ent0 == ent1
        for s in (s0, s1):
            # the range that ran first had its flag or note overwritten in the journal; the pass restored it
            (entry,) = s["trajectory_pass"]
            assert entry["changed"] == [[BONE, KEY]] and entry["review_flagged"] == {BONE: 1}
            (line,) = [m for m in pass_messages(entry) if f"frame {KEY}:" in m]
            assert FLAG in line and "off the trajectory" not in line  # it never was
            assert entry["changes"][0]["was_off_trajectory"] is False


def test_no_range_flagging_the_shared_keyframe_keeps_the_journals_note(keyed, tmp_path, monkeypatch):
    for rev in (False, True):
        rec, _, s, _ = _run(keyed, tmp_path, monkeypatch, f"none{int(rev)}", rev, "neither")
        assert not [x for x in rec["flags"] if x.startswith(FLAG)]
        (note,) = [x for x in rec["notes"] if x.startswith(NOTE)]  # the range recorded last
        assert ("frames 11 and 10" in note) is rev  # the backward range's prediction when it ran last
        (entry,) = s["trajectory_pass"]
        assert entry["changed"] == []  # not journaled again for a note


def test_merge_of_synthetic_records_ignores_task_order_and_an_unreadable_report():
    # no study: the journal's record and the two range reports as dicts, the reports in both orders
    from types import SimpleNamespace

    from core.tracking.batch_pass import _shared_first_frames

    back = SimpleNamespace(order=[12, 11, 10], report_name="back", key="k:12-10")
    fwd = SimpleNamespace(order=[12, 13, 14], report_name="fwd", key="k:12-14")
    flag, note = f"{FLAG} (fwd)", f"{NOTE} (back)"
    reports = {"back": {"frames_done": [{"bone": BONE, "frame": 12, "flags": [], "notes": [note]}]},
               "fwd": {"flagged": [{"bone": BONE, "frame": 12, "flags": [flag], "notes": []}]}}
    P = np.eye(4)

    def read(kind, name):
        return reports[name]

    for journal in (FrameResult(BONE, 12, P, 0.8, 10, 0.0, True, notes=("other", note)),
                    FrameResult(BONE, 12, P, 0.8, 10, 0.0, True, (flag,))):
        for tasks in ([back, fwd], [fwd, back]):
            got = _shared_first_frames({(BONE, 12): journal}, tasks, [BONE], read)[(BONE, 12)]
            assert got.flags == (flag,) and note in got.notes
    # the flagging range's report unreadable: the journal's note stays, nothing invented
    journal = FrameResult(BONE, 12, P, 0.8, 10, 0.0, True, notes=(note,))

    def unreadable(kind, name):
        if name == "fwd":
            raise OSError("removed")
        return reports[name]

    got = _shared_first_frames({(BONE, 12): journal}, [back, fwd], [BONE], unreadable)[(BONE, 12)]
    assert got is journal
