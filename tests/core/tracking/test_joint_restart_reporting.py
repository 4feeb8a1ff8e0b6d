"""What ``track_study`` and a ``talus batch`` task record of ``TrackingOptions.joint_restart`` and
``joint_rounds`` (core.tracking.from_study, core.tracking.batch): a joint run's report and a joint
task's record say its rounds and whether those after the first started from the prediction; the
options reach the tracker as given, on resume too, with a note where the run being resumed recorded
other ones (none recorded: two rounds, the default before); a sequential run records nothing of them.
The tracker is replaced (the options it gets are checked), on the shared
48² demo walk."""

from __future__ import annotations

import shutil

import pytest

from core.study import Study
from core.tracking.from_study import track_study
from tests.core.tracking.test_sequential_subtract_reporting import (
    CORRECTED,
    _old_report,
    _tracked_frame_1,
)
from tests.core.tracking.test_sequential_subtract_reporting import seen as seen


@pytest.fixture
def demo(demo_walk_48, tmp_path):
    return shutil.copytree(demo_walk_48, tmp_path / "demo")


def _opts(mode="joint", restart=False, rounds=2):
    from core.tracking.trial import TrackingOptions

    return TrackingOptions(mode=mode, confidence=False, joint_restart=restart, joint_rounds=rounds)


def _run(demo, opts, **kw):
    with Study.open(demo, mode="w") as st:
        _, rep = track_study(st, "walk", ["talus", "calcaneus"], [1, 2], correction=CORRECTED, options=opts,
                             device="cpu", **kw)
    return rep


@pytest.mark.parametrize("restart", [False, True])
def test_joint_report_records_the_choice(demo, seen, restart):
    rep = _run(demo, _opts(restart=restart))
    assert seen["options"].joint_restart is restart
    assert rep["options"]["mode"] == "joint" and rep["options"]["joint_restart"] is restart
    assert rep["options"]["joint_rounds"] == 2 and "joint_restart_note" not in rep["options"]
    rep = _run(demo, _opts("sequential", restart))  # sequential tracking: nothing to record
    assert "joint_restart" not in rep["options"] and "joint_rounds" not in rep["options"]
    rep = _run(demo, _opts(rounds=1))  # the default, recorded as such
    assert seen["options"].joint_rounds == 1 and rep["options"]["joint_rounds"] == 1


@pytest.mark.parametrize(("recorded", "restart"), [(True, True), (None, False), (True, False), (None, True)])
def test_resume_keeps_the_choice_and_notes_another(demo, seen, recorded, restart):
    """Resumed, the option is used as given and recorded; where the run being resumed recorded the
    other choice (none recorded: off, a run from before the option) the note says so."""
    _tracked_frame_1(demo)
    old = {"mode": "joint", "resume": False}
    if recorded is not None:
        old["joint_restart"] = recorded
    _old_report(demo, old)
    rep = _run(demo, _opts(restart=restart), resume=True)
    assert seen["options"].joint_restart is restart
    assert rep["options"]["joint_restart"] is restart
    note = rep["options"].get("joint_restart_note")
    if bool(recorded) == restart:
        assert note is None
    else:
        assert note.startswith(f"resumed with joint restart {'on' if restart else 'off'}"), note
    # the report now records this run's choice: resumed again with it, no note
    assert "joint_restart_note" not in _run(demo, _opts(restart=restart), resume=True)["options"]


def test_resume_with_nothing_tracked_has_no_note(demo, seen):
    _old_report(demo, {"mode": "joint", "joint_restart": True})
    rep = _run(demo, _opts(), resume=True)
    assert rep["options"]["joint_restart"] is False and "joint_restart_note" not in rep["options"]


@pytest.mark.parametrize(("recorded", "rounds", "restart", "note"), [
    (None, 2, False, None),  # a report from before the option: two rounds
    (None, 1, False, "resumed with 1 joint round: the frames tracked before ran with 2 joint rounds"),
    (1, 2, True, "resumed with 2 joint rounds, joint restart on: the frames tracked before ran with 1 joint "
                 "round, joint restart off"),
    (3, 3, False, None)])
def test_resume_notes_other_rounds(demo, seen, recorded, rounds, restart, note):
    """Resumed with other rounds than the run being resumed recorded (none recorded: two, the default
    before), the note says so (and the restart too where it differs as well); the options used as
    given."""
    _tracked_frame_1(demo)
    old = {"mode": "joint", "resume": False}
    if recorded is not None:
        old["joint_rounds"] = recorded
    _old_report(demo, old)
    rep = _run(demo, _opts(restart=restart, rounds=rounds), resume=True)
    assert seen["options"].joint_rounds == rounds and rep["options"]["joint_rounds"] == rounds
    assert rep["options"].get("joint_restart_note") == note


@pytest.mark.parametrize("restart", [False, True])
def test_batch_task_records_the_choice(demo, seen, restart):
    """A joint task gets the option through its settings and records it, in its record and its end
    event; run again (resume), the same; a task of one bone (sequential) records None."""
    from core.tracking.batch import BatchTask, TaskSettings, run_task

    settings = TaskSettings(device="cpu", confidence=False,
                            options=(("joint_restart", restart), ("joint_rounds", 1 + restart)))
    assert settings.tracking_options(joint=True).joint_restart is restart
    task = BatchTask(str(demo), "walk", ("talus", "calcaneus"), (1, 2))
    ends = []
    for _ in range(2):
        rec = run_task(task, settings, progress=lambda e: ends.append(e) if e["kind"] == "end" else None)
        assert seen["options"].joint_restart is restart
        assert rec["mode"] == "joint" and rec["joint_restart"] is restart
        assert rec["joint_rounds"] == 1 + restart and rec["joint_restart_note"] is None
        # the end event says it too (the window's Batch dock shows it before the records come)
        assert (ends[-1]["joint_rounds"], ends[-1]["joint_restart"], ends[-1]["joint_restart_note"]) == (
            1 + restart, restart, None)
    rec = run_task(BatchTask(str(demo), "walk", ("talus",), (1, 2)), settings, progress=ends.append)
    assert rec["mode"] == "sequential" and rec["joint_restart"] is None and rec["joint_rounds"] is None
    assert ends[-1]["kind"] == "end" and ends[-1]["joint_restart"] is None
    assert ends[-1]["joint_rounds"] is None
