"""What ``track_study`` reports and keeps of ``TrackingOptions.sequential_subtract``
(core.tracking.from_study): a one-bone sequential run subtracts nothing and says so (false, with a
note when the choice was on); on resume, auto keeps the choice the run being resumed recorded in
its report (off where it recorded none) or, without that report, what the trial's other reports
(``talus batch`` tasks', ``--split-bones`` or ranges) say where they agree — else auto as for a new
run, the note saying why; explicit choices still win, and a run with nothing to carry on decides as
a new one. The tracker is replaced (the options it gets are checked), on the
shared 48² demo walk."""

from __future__ import annotations

import shutil

import numpy as np
import pytest

from core.study import Study
from core.tracking import from_study
from core.tracking.from_study import track_study

CORRECTED = [lambda raw: np.clip(np.asarray(raw, np.float32) / 4095.0, 0, 1)] * 2


@pytest.fixture
def demo(demo_walk_48, tmp_path):
    return shutil.copytree(demo_walk_48, tmp_path / "demo")


@pytest.fixture
def seen(monkeypatch):
    import types

    import core.render
    from core.tracking.trial import TrackingResult

    got = {}
    monkeypatch.setattr(core.render, "DRRRenderer",
                        lambda rig, volumes, **kw: types.SimpleNamespace(volumes=volumes))

    def fake_track(renderer, bones, frames, order, *, options=None, **kw):
        got["options"] = options
        return TrackingResult(tuple(b.name for b in bones), tuple(order), {}, "complete", 0.0)

    monkeypatch.setattr(from_study, "track", fake_track)
    return got


def _opts(subtract=None):
    from core.tracking.trial import TrackingOptions

    return TrackingOptions(mode="sequential", confidence=False, sequential_subtract=subtract)


@pytest.mark.parametrize("subtract", [None, True, False])
def test_one_bone_reports_nothing_subtracted(demo, seen, subtract):
    with Study.open(demo, mode="w") as st:
        _, rep = track_study(st, "walk", ["talus"], [1], correction=CORRECTED, options=_opts(subtract),
                             device="cpu")
    assert rep["options"]["sequential_subtract"] is False  # no other bone: nothing subtracted
    note = rep["options"].get("sequential_subtract_note")
    if subtract is False:
        assert note is None
    else:  # the choice (auto on these frames, or on) was on: the note says why nothing was
        assert "no other bone tracked" in note
    # several bones: as before
    with Study.open(demo, mode="w") as st:
        _, rep = track_study(st, "walk", ["talus", "calcaneus"], [1], correction=CORRECTED,
                             options=_opts(subtract), device="cpu")
    assert rep["options"]["sequential_subtract"] is (subtract is not False)
    assert "sequential_subtract_note" not in rep["options"]


def _tracked_frame_1(study_folder, bones=("talus", "calcaneus")) -> None:
    """Frame 1 of ``bones`` journaled as tracking results (a run cut off after it)."""
    from core.tracking.results import FrameResult

    with Study.open(study_folder, mode="w") as st:
        t = st.trial("walk")
        for b in bones:
            pose = np.load(study_folder / "poses" / f"{b}.npy")[1]
            t.record_pose(b, 1, pose, score=0.9,
                          tracking=FrameResult(b, 1, pose, 0.9, 10, 0.1, True).journal_fields())


def _old_report(study_folder, options: dict) -> None:
    with Study.open(study_folder, mode="w") as st:
        st.write_report("tracking", "walk", {"trial": "walk", "options": options})


@pytest.mark.parametrize("recorded", [None, True, False])
def test_resume_keeps_the_recorded_choice(demo, seen, recorded):
    """Auto on flatfield-corrected frames is on for a new run; resumed, the run's recorded choice
    (absent: a run from before the default, off) stands, and the report's note says so."""
    _tracked_frame_1(demo)
    old = {"mode": "sequential", "resume": False}
    if recorded is not None:
        old["sequential_subtract"] = recorded
    _old_report(demo, old)
    with Study.open(demo, mode="w") as st:
        _, rep = track_study(st, "walk", ["talus", "calcaneus"], [1, 2], correction=CORRECTED,
                             options=_opts(), device="cpu", resume=True)
    want = bool(recorded)  # None: off
    assert seen["options"].sequential_subtract is want
    assert rep["options"]["sequential_subtract"] is want
    note = rep["options"]["sequential_subtract_note"]
    assert note.startswith("resumed") and "run being resumed" in note
    assert ("recorded no choice" in note) is (recorded is None)
    # the report now records the choice: resumed again, the same
    with Study.open(demo, mode="w") as st:
        _, rep = track_study(st, "walk", ["talus", "calcaneus"], [1, 2], correction=CORRECTED,
                             options=_opts(), device="cpu", resume=True)
    assert seen["options"].sequential_subtract is want
    assert "recorded no choice" not in rep["options"]["sequential_subtract_note"]


def test_resume_of_one_bone_says_nothing_subtracted(demo, seen):
    """One bone resumed (a ``talus batch`` task, always resumed): nothing to subtract or keep."""
    _tracked_frame_1(demo, ("talus",))
    _old_report(demo, {"mode": "sequential"})
    with Study.open(demo, mode="w") as st:
        _, rep = track_study(st, "walk", ["talus"], [1, 2], correction=CORRECTED, options=_opts(),
                             device="cpu", resume=True)
    assert rep["options"]["sequential_subtract"] is False
    assert "no other bone tracked" in rep["options"]["sequential_subtract_note"]


@pytest.mark.parametrize("subtract", [True, False])
def test_resume_explicit_choice_wins(demo, seen, subtract):
    _tracked_frame_1(demo)
    _old_report(demo, {"mode": "sequential", "sequential_subtract": not subtract})
    with Study.open(demo, mode="w") as st:
        _, rep = track_study(st, "walk", ["talus", "calcaneus"], [1, 2], correction=CORRECTED,
                             options=_opts(subtract), device="cpu", resume=True)
    assert seen["options"].sequential_subtract is subtract
    assert rep["options"]["sequential_subtract"] is subtract
    assert "sequential_subtract_note" not in rep["options"]


def test_resume_with_nothing_tracked_decides_as_a_new_run(demo, seen):
    """No tracking result in the range (only the keyframes), or a joint run's report: auto as
    usual (on for flatfield-corrected frames), no note."""
    _old_report(demo, {"mode": "sequential"})  # a report, but nothing of frames 1-2 tracked
    with Study.open(demo, mode="w") as st:
        _, rep = track_study(st, "walk", ["talus", "calcaneus"], [1, 2], correction=CORRECTED,
                             options=_opts(), device="cpu", resume=True)
    assert seen["options"].sequential_subtract is True
    assert "sequential_subtract_note" not in rep["options"]
    _tracked_frame_1(demo)
    _old_report(demo, {"mode": "joint"})
    with Study.open(demo, mode="w") as st:
        _, rep = track_study(st, "walk", ["talus", "calcaneus"], [1, 2], correction=CORRECTED,
                             options=_opts(), device="cpu", resume=True)
    assert seen["options"].sequential_subtract is True
    # without a report at all: the earlier frames' method is unknown, auto as for a new run (on)
    (demo / "results" / "reports" / "tracking" / "walk.json").unlink()
    with Study.open(demo, mode="w") as st:
        _, rep = track_study(st, "walk", ["talus", "calcaneus"], [1, 2], correction=CORRECTED,
                             options=_opts(), device="cpu", resume=True)
    assert seen["options"].sequential_subtract is True
    note = rep["options"]["sequential_subtract_note"]
    assert note.startswith("resumed: neighbours subtracted (auto, as for a new run)")
    assert "method is unknown" in note


def _task_report(study_folder, name: str, bones, options: dict) -> None:
    """A ``talus batch`` task's report of frame 1 of ``bones`` (``frames_done``, as older reports
    name their bones)."""
    with Study.open(study_folder, mode="w") as st:
        st.write_report("tracking", name, {"trial": "walk", "options": options,
                                           "frames_done": [{"bone": b, "frame": 1} for b in bones]})


ONE_BONE = {"mode": "sequential", "sequential_subtract": False,
            "sequential_subtract_note": "on, but no other bone tracked: nothing to subtract"}


def test_resume_after_split_bones_tasks_keeps_each_bone_alone(demo, seen):
    """Frames tracked by ``talus batch --split-bones`` tasks (reports walk.talus, walk.calcaneus; no
    walk.json), resumed as one sequential run: their searches did not subtract, so neither does the
    rest of the trial, and the note names the tasks' reports."""
    _tracked_frame_1(demo)
    for b in ("talus", "calcaneus"):
        _task_report(demo, f"walk.{b}", [b], ONE_BONE)
    _task_report(demo, "walk.tibia", ["tibia"], {"mode": "sequential", "sequential_subtract": True})
    _task_report(demo, "walk.talus.0-9", ["talus", "calcaneus"], {"mode": "joint"})  # left out
    with Study.open(demo, mode="w") as st:
        _, rep = track_study(st, "walk", ["talus", "calcaneus"], [1, 2], correction=CORRECTED,
                             options=_opts(), device="cpu", resume=True)
    assert seen["options"].sequential_subtract is False
    assert rep["options"]["sequential_subtract"] is False
    assert rep["options"]["sequential_subtract_note"] == (
        "resumed: neighbours not subtracted (auto), as the trial's earlier runs did: "
        "walk.calcaneus (one bone), walk.talus (one bone)")
    # the report, written as the run starts, records the choice and the bones: resumed again, the same
    with Study.open(demo) as st:
        assert st.read_report("tracking", "walk")["bones"] == ["talus", "calcaneus"]
    with Study.open(demo, mode="w") as st:
        _, rep = track_study(st, "walk", ["talus", "calcaneus"], [1, 2], correction=CORRECTED,
                             options=_opts(), device="cpu", resume=True)
    assert seen["options"].sequential_subtract is False
    assert "as the run being resumed recorded" in rep["options"]["sequential_subtract_note"]


def test_resume_after_range_tasks_keeps_their_choice_or_decides_when_they_differ(demo, seen):
    """Sequential range tasks' reports (walk.0-4, walk.5-9) that subtracted: kept by a resumed
    whole-trial run. One of them searched alone (off): they differ, auto decides (off on frames
    divided by the full scale), and the note lists both."""
    _tracked_frame_1(demo)
    on = {"mode": "sequential", "sequential_subtract": True}
    _task_report(demo, "walk.0-4", ["talus", "calcaneus"], on)
    _task_report(demo, "walk.5-9", ["talus", "calcaneus"], on)
    with Study.open(demo, mode="w") as st:
        _, rep = track_study(st, "walk", ["talus", "calcaneus"], [1, 2], options=_opts(), device="cpu",
                             resume=True)  # frames divided by the full scale: auto alone is off
    assert seen["options"].sequential_subtract is True
    assert rep["options"]["sequential_subtract_note"].endswith("earlier runs did: walk.0-4, walk.5-9")
    (demo / "results" / "reports" / "tracking" / "walk.json").unlink()
    _task_report(demo, "walk.5-9", ["talus", "calcaneus"], {**on, "sequential_subtract": False})
    with Study.open(demo, mode="w") as st:
        _, rep = track_study(st, "walk", ["talus", "calcaneus"], [1, 2], options=_opts(), device="cpu",
                             resume=True)
    assert seen["options"].sequential_subtract is False
    assert rep["options"]["sequential_subtract_note"] == (
        "resumed: neighbours not subtracted (auto, as for a new run): the trial's earlier runs differ: "
        "walk.0-4, walk.5-9 (off)")


def test_cli_summary_gives_the_note(demo, monkeypatch, capsys):
    """``talus track``'s JSON summary (and stderr) carries the report's note."""
    import json

    from app.cli import main as talus

    rep = {"summary": {"status": "complete"}, "options": {
        "mode": "sequential", "sequential_subtract": False,
        "sequential_subtract_note": "on, but no other bone tracked: nothing to subtract"}}
    monkeypatch.setattr(from_study, "track_study", lambda *a, **k: (None, rep))
    talus(["track", str(demo), "--trial", "walk", "--bones", "talus", "--frames", "1:2",
           "--mode", "sequential", "--sequential-subtract", "on", "--device", "cpu", "--quiet"])
    cap = capsys.readouterr()
    out = json.loads(cap.out)
    assert out["sequential_subtract"] is False
    assert out["sequential_subtract_note"] == rep["options"]["sequential_subtract_note"]
    assert "no other bone tracked" in cap.err
