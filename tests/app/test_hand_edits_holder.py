"""A refused hand edit names what holds the bone's journal: the lock's holder line says it."""

import os
import socket

from app.hand_edits import WINDOW_EDIT, holder_text
from core.tracking.batch_journal import BATCH_TASK, RANGE_APPEND
from core.tracking.from_study import TRACK_COMMAND, WINDOW_TRACKING


def _here(by: str) -> dict:
    return {"pid": os.getpid(), "host": socket.gethostname(), "since": "12:00:00", "by": by}


def test_holders_in_this_process_are_named():
    assert holder_text(_here(BATCH_TASK)) == "this window's batch (a task tracking the bone)"
    assert holder_text(_here(RANGE_APPEND)) == "this window's batch (a range task's append)"
    assert holder_text(_here(WINDOW_TRACKING)) == "this window's tracking job"
    assert holder_text(_here(TRACK_COMMAND)) == ("another handle of the study in this program since 12:00:00 "
                                                 "(talus track)")


def test_another_handle_here_that_says_nothing_of_itself():
    assert holder_text(_here("")) == ("another handle of the study in this program since 12:00:00 "
                                      "(what holds it is not recorded)")


def test_another_process_is_named_by_what_it_records():
    other = {"pid": 1, "host": "lab-pc", "since": "12:00:00", "by": TRACK_COMMAND}
    assert holder_text(other) == "process 1 on lab-pc since 12:00:00 (talus track)"
    assert holder_text({**other, "by": BATCH_TASK}) == ("process 1 on lab-pc since 12:00:00 (a talus batch "
                                                        "task tracking the bone)")
    assert "another program" in holder_text({**other, "by": ""})
    assert holder_text({}) == "another writer"


def test_a_window_in_another_process_is_not_this_window():
    """'the window's hand edit' of another process read as this window's own."""
    other = {"pid": 1, "host": "lab-pc", "since": "12:00:00"}
    assert holder_text({**other, "by": WINDOW_EDIT}) == ("process 1 on lab-pc since 12:00:00 (another "
                                                         "window's hand edit)")
    assert holder_text({**other, "by": WINDOW_TRACKING}).endswith("(another window's tracking job)")


def test_track_study_records_what_holds_the_journal(tmp_path):
    """The holder line of a journal locked by track_study's way (Study.lock_journal with by=)."""
    from core.io.atomic import FileLock

    lock = FileLock(tmp_path / ".talus.lock", purpose="bone 'talus'", by=TRACK_COMMAND).acquire()
    try:
        try:
            FileLock(tmp_path / ".talus.lock", purpose="bone 'talus'").acquire()
        except Exception as exc:  # LockedError names the holder
            assert getattr(exc, "holder", {}).get("by") == TRACK_COMMAND
            assert "talus track" in str(exc)
        else:
            raise AssertionError("a second lock of the same journal was granted")
    finally:
        lock.release()


def test_track_study_passes_what_tracks(tmp_path, monkeypatch):
    """track_study locks each bone's journal saying what tracks it (talus track by default, the
    window's tracking job when the window asks); stopped right there by the fake lock."""
    from core.study import Study
    from core.tracking.from_study import track_study

    from ._helpers import small_demo

    folder = small_demo(tmp_path / "demo")
    seen = []

    class Stop(Exception):
        pass

    def lock_journal(self, trial, bone, *, timeout=0.0, by=""):
        seen.append(by)
        raise Stop

    monkeypatch.setattr(Study, "lock_journal", lock_journal)
    with Study.open(folder, mode="w") as st:
        trial = st.trials[0]
        for kw, want in (({}, TRACK_COMMAND), ({"lock_by": WINDOW_TRACKING}, WINDOW_TRACKING)):
            try:
                track_study(st, trial, device="cpu", **kw)
            except Stop:
                pass
            assert seen[-1] == want
