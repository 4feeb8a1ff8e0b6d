"""Lock granularity between real processes: writers lock the bone journal they write, the manifest
only for one read-modify-write, so processes tracking different bones or trials of one study work
side by side and two on one bone are refused."""

import json

import numpy as np
import pytest

from core.study import LockedError, Study

# a writer process: journals N poses of one bone (holding its lock), then edits the manifest
WRITER = """
import os, sys, time
import numpy as np
from core.geometry import make_rigid
from core.study import Study, LockedError
st = Study.open({folder!r}, mode="w")
try:
    st.lock_journal({trial!r}, {bone!r})
except LockedError as exc:
    print("refused:", exc, flush=True)
    sys.exit(3)
print("locked", flush=True)
while not os.path.exists({go!r}):  # wait until every writer holds its lock
    time.sleep(0.01)
tr = st.trial({trial!r})
for i in range(6):
    tr.record_pose({bone!r}, i, make_rigid(np.eye(3), [{k}, i, 0]), score={k} / 10)
for i in range(20):  # many short manifest updates, interleaved with the other writers'
    st.update_settings(**{{"{trial}.{bone}": i}})
print("done", flush=True)
st.close()
"""


@pytest.fixture
def folder(tmp_path, rig_files, views):
    with Study.create(tmp_path / "st") as st:
        st.add_calibration("day1", rig_files)
        vol = tmp_path / "ct.tif"
        vol.write_bytes(b"placeholder")
        st.add_volume("ct", vol, voxel_size_mm=[1, 1, 1])
        for b in ("talus", "calcaneus"):
            st.add_bone(b, volume="ct")
        for t in ("walk01", "walk02"):
            st.add_trial(t, views[0], calibration="day1", bones=["talus", "calcaneus"])
    return tmp_path / "st"


def test_writers_of_different_bones_and_trials_work_side_by_side(folder, python_child):
    jobs = [("walk01", "talus"), ("walk01", "calcaneus"), ("walk02", "talus")]
    go = folder.parent / "go"
    children = [python_child.start(WRITER.format(folder=str(folder), trial=t, bone=b, k=k, go=str(go)))
                for k, (t, b) in enumerate(jobs)]
    for c in children:
        assert c.stdout.readline().strip() == "locked", c.stderr.read()
    # a fourth process on a bone in use is refused at once, naming the bone and its holder
    same = python_child.start(WRITER.format(folder=str(folder), trial="walk01", bone="talus", k=9,
                                            go=str(go)))
    assert same.wait(timeout=60) == 3
    refusal = same.stdout.read()
    assert (f"refused: bone 'talus' of trial 'walk01' in study {folder} is locked for writing by "
            f"process {children[0].pid}") in refusal
    go.touch()
    for c in children:
        out, err = c.communicate(timeout=120)
        assert c.returncode == 0 and out.strip() == "done", err
    with Study.open(folder) as st:
        for k, (t, b) in enumerate(jobs):
            P = st.trial(t).poses(b)
            np.testing.assert_array_equal(P[:, 0, 3], np.full(6, k))  # every writer's poses, intact
            np.testing.assert_array_equal(P[:, 1, 3], np.arange(6))
            assert st.settings[f"{t}.{b}"] == 19  # no manifest update was lost to another's
        assert np.isnan(st.trial("walk02").poses("calcaneus")).all()
    doc = json.loads((folder / "study.json").read_text())
    assert set(doc["trials"]) == {"walk01", "walk02"} and set(doc["bones"]) == {"talus", "calcaneus"}


def test_manifest_edits_of_two_handles_merge(folder, tmp_path, views):
    a = Study.open(folder, mode="w")
    b = Study.open(folder, mode="w")  # e.g. a second process, opened before a's edits
    try:
        a.update_settings(from_a=1)
        a.add_trial("walk03", views[0], calibration="day1", bones=["talus"])
        b.update_settings(from_b=2)
        b.add_trial("walk04", views[0], calibration="day1", bones=["calcaneus"])
    finally:
        a.close()
        b.close()
    with Study.open(folder) as st:
        assert st.trials == ("walk01", "walk02", "walk03", "walk04")
        assert st.settings == {"from_a": 1, "from_b": 2}


def test_one_handle_keeps_its_journal_locks_until_closed(folder):
    a = Study.open(folder, mode="w")
    b = Study.open(folder, mode="w")
    try:
        a.trial("walk01").record_pose("talus", 0, np.eye(4))  # the first write locks the journal
        assert a.journal_locked("walk01", "talus") and not b.journal_locked("walk01", "talus")
        with pytest.raises(LockedError, match="bone 'talus' of trial 'walk01'"):
            b.trial("walk01").record_pose("talus", 1, np.eye(4))
        b.trial("walk01").record_pose("calcaneus", 1, np.eye(4))  # another bone: fine
        a.lock_journal("walk01", "talus")  # idempotent
        with pytest.raises(LockedError, match="bone 'calcaneus' of trial 'walk01'"):
            a.lock_journal("walk01", "calcaneus")
    finally:
        a.close()
    b.lock_journal("walk01", "talus")  # released by a's close
    b.close()


def test_lock_journal_waits_up_to_its_timeout(folder):
    """``timeout``: a journal held for a moment (talus batch's trajectory check) is waited for; one
    held past it is refused, as one is at once without it."""
    import threading

    a, b = Study.open(folder, mode="w"), Study.open(folder, mode="w")
    try:
        a.lock_journal("walk01", "talus")
        with pytest.raises(LockedError, match="bone 'talus' of trial 'walk01'"):
            b.lock_journal("walk01", "talus", timeout=0.1)
        threading.Timer(0.2, a.unlock_journal, ("walk01", "talus")).start()
        b.lock_journal("walk01", "talus", timeout=10.0)
        assert b.journal_locked("walk01", "talus")
        with pytest.raises(LockedError):
            a.lock_journal("walk01", "talus")
    finally:
        a.close()
        b.close()


def test_hold_lock_keeps_a_further_lock_until_closed(folder):
    """hold_lock: a lock file of the study (the window's results/<trial>/.window.lock) held by one
    handle until it is closed; a second handle is refused, naming the lock's purpose and the holder;
    read-only handles may not take one."""
    from core.study import StudyError

    a, b = Study.open(folder, mode="w"), Study.open(folder, mode="w")
    try:
        what = "trial 'walk01' (edited in another window)"
        a.hold_lock("results/walk01/.window.lock", purpose=what)
        with pytest.raises(LockedError, match=r"window\) is locked for writing by process"):
            b.hold_lock("results/walk01/.window.lock", purpose=what)
        b.lock_journal("walk01", "talus")  # the journals are not held by it
    finally:
        a.close()
    b.hold_lock("results/walk01/.window.lock", purpose="x")  # released by a's close
    b.close()
    with Study.open(folder) as r, pytest.raises(StudyError):
        r.hold_lock("results/walk01/.window.lock", purpose="x")


def test_a_journal_taken_again_is_repaired_only_after_other_appends(folder, monkeypatch):
    """The window takes a journal per hand fix (lock, append, unlock): the torn-tail repair, which
    reads the whole journal, runs again only where another writer appended meanwhile (or the tail
    was torn), not on every move of a drag."""
    import core.study.trial as trial_mod

    calls = []
    real = trial_mod.repair_tail
    monkeypatch.setattr(trial_mod, "repair_tail", lambda p: calls.append(p) or real(p))
    a, b = Study.open(folder, mode="w"), Study.open(folder, mode="w")
    try:
        ta = a.trial("walk01")
        for f in range(3):  # three edits, each under the lock for its append only
            ta.record_pose("talus", f, np.eye(4))
            a.unlock_journal("walk01", "talus")
        assert len(calls) == 1  # the first
        b.trial("walk01").record_pose("talus", 5, np.eye(4))  # another writer appends
        b.unlock_journal("walk01", "talus")
        ta.record_pose("talus", 3, np.eye(4))
        assert len(calls) == 3  # b's first write, and a's after b's append
        a.unlock_journal("walk01", "talus")
        path = calls[0]
        with open(path, "ab") as fh:  # a torn record (a writer died mid-append)
            fh.write(b'{"frame": 7, "po')
        ta.record_pose("talus", 4, np.eye(4))
        assert len(calls) == 4
        assert set(a.trial("walk01").results("talus").records) == {0, 1, 2, 3, 4, 5}
    finally:
        a.close()
        b.close()


def test_a_journal_rewritten_to_its_old_size_with_a_torn_tail_is_repaired(folder):
    """The repair is skipped where the journal is as this handle left it. Its size alone did not say
    so: another writer's compaction (an atomic rewrite) followed by a torn append can leave it the
    size it was; our next record was then glued onto the torn one, both lost. The journal's file and
    modification time are compared too."""
    import os

    a = Study.open(folder, mode="w")
    try:
        ta = a.trial("walk01")
        for f in range(3):
            ta.record_pose("talus", f, np.eye(4))
        a.unlock_journal("walk01", "talus")
        path = folder / "results" / "walk01" / "poses" / "talus.jsonl"
        data = path.read_bytes()
        tmp = path.with_name("talus.jsonl.tmp")  # the rewrite: frames 0-1 whole, frame 2 torn, same size
        tmp.write_bytes(data[:-1] + b"x")
        os.replace(tmp, path)
        assert path.stat().st_size == len(data)
        ta.record_pose("talus", 3, np.eye(4))
        state = a.trial("walk01").results("talus")
        assert set(state.records) == {0, 1, 3} and not state.torn_bytes
    finally:
        a.close()


def test_a_journal_locked_again_names_its_current_holder(folder):
    """A handle that holds a bone's journal and locks it again with another ``by`` (a tracker
    starting after a script's first write took the lock unnamed; the window's tracking job after a
    hand edit) records that holder: a writer refused then names what writes the bone now. The lock
    is kept throughout; an empty ``by`` (a write locking on its own) keeps the name."""
    a, b = Study.open(folder, mode="w"), Study.open(folder, mode="w")
    try:
        a.trial("walk01").record_pose("talus", 0, np.eye(4))  # locked, nothing named
        with pytest.raises(LockedError) as refused:
            b.lock_journal("walk01", "talus")
        assert "by" not in refused.value.holder
        for by in ("talus track", "the window's tracking job"):
            a.lock_journal("walk01", "talus", by=by)
            assert a.journal_locked("walk01", "talus")
            with pytest.raises(LockedError, match=f"bone 'talus' of trial 'walk01'.*\\({by}\\)") as refused:
                b.lock_journal("walk01", "talus")
            assert refused.value.holder["by"] == by
        a.trial("walk01").record_pose("talus", 1, np.eye(4))  # a write: the name stays
        a.lock_journal("walk01", "talus")
        with pytest.raises(LockedError) as refused:
            b.lock_journal("walk01", "talus")
        assert refused.value.holder["by"] == "the window's tracking job"
        a.unlock_journal("walk01", "talus")
        b.lock_journal("walk01", "talus", by="talus batch")  # a lock taken anew names its own holder
        with pytest.raises(LockedError) as refused:
            a.lock_journal("walk01", "talus")
        assert refused.value.holder["by"] == "talus batch"
    finally:
        a.close()
        b.close()
