"""``talus batch --mode sequential``: one task per trial whose bones are tracked one after another with
the others' DRRs subtracted — the poses ``talus track --mode sequential`` gives (track_study with the
same options), bit for bit, on the 48² demo walk on Warp's CPU device; ``split_bones`` one task per
bone, which says it cannot subtract; the choice that ran in every record, kept on resume (also
where ``--split-bones`` tasks tracked the frames before)."""

from __future__ import annotations

import shutil

import numpy as np
import pytest

from core.study import Study
from core.tracking.batch import BatchTask, TaskSettings, build_tasks, run_serial
from core.tracking.from_study import track_study
from core.tracking.register import Level, RegistrationOptions
from tests.core.tracking.batch_helpers import save_flat_calibration

BONES = ("talus", "calcaneus")
FRAMES = 2
# one short CMA-ES level per frame, no first-frame restarts (as test_batch: a quick batch)
_FAST = RegistrationOptions(bounds=(5.0, 5.0), refine="pattern", levels=(
    Level(1.0, "cmaes", (1.0, 1.0), popsize=10, max_generations=40, tol_x=0.02),))
OPTIONS = (("verify_restarts", 0), ("registration", _FAST), ("first", _FAST))
SETTINGS = TaskSettings(device="cpu", confidence=False, frames=(0, FRAMES), options=OPTIONS)


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory, demo_walk_48):
    """The demo walk with its frames flatfield-corrected by a saved calibration (so sequential
    tracking subtracts the neighbours by default, as on a calibrated study)."""
    out = shutil.copytree(demo_walk_48, tmp_path_factory.mktemp("seq") / "demo")
    save_flat_calibration(out, ["walk"])
    return out


def test_sequential_groups_a_trials_bones_unless_split(calibrated, demo_walk_48):
    folder = str(calibrated.absolute())
    (task,) = build_tasks([calibrated], bones=list(BONES), mode="sequential")
    assert task == BatchTask(folder, "walk", BONES, mode="sequential")
    assert task.tracking_mode == "sequential" and task.report_name == "walk"  # talus track's report
    assert build_tasks([calibrated], bones=list(BONES), joint=False) == [task]
    split = build_tasks([calibrated], bones=list(BONES), mode="sequential", split_bones=True)
    assert split == [BatchTask(folder, "walk", (b,)) for b in BONES]
    assert all(t.tracking_mode == "sequential" for t in split)
    (joint,) = build_tasks([calibrated], bones=list(BONES))  # auto: jointly on corrected frames
    assert joint.tracking_mode == "joint" and joint.mode is None
    # auto on frames divided by the full scale: one task per bone (nothing subtracted there, the
    # bones independent), unless the neighbours are asked subtracted (--sequential-subtract on)
    assert [t.bones for t in build_tasks([demo_walk_48], bones=list(BONES))] == [("talus",), ("calcaneus",)]
    (grouped,) = build_tasks([demo_walk_48], bones=list(BONES), subtract=True)
    assert grouped.bones == BONES and grouped.tracking_mode == "sequential"
    ranged = build_tasks([calibrated], bones=list(BONES), mode="sequential", ranges=True, frames=(0, 3))
    assert [(t.bones, t.frames, t.mode) for t in ranged] == [(BONES, (0, 2), "sequential")]
    with pytest.raises(ValueError, match="split_bones: one task per bone is a choice of mode 'sequential'"):
        build_tasks([calibrated], split_bones=True)
    with pytest.raises(ValueError, match="mode: expected None, 'joint' or 'sequential'"):
        BatchTask(folder, "walk", BONES, mode="auto")


def test_a_sequential_task_gives_talus_tracks_poses(calibrated, tmp_path):
    """The batch's sequential task and track_study(mode="sequential") — what ``talus track --mode
    sequential`` runs — with the same options, on copies of one study: the same poses, bit for bit,
    the neighbours subtracted in both; the record says so. Split, each bone's task says it could
    not subtract."""
    ref, got, split = (shutil.copytree(calibrated, tmp_path / n) for n in ("ref", "batch", "split"))
    with Study.open(ref, mode="w") as st:
        _, report = track_study(st, "walk", list(BONES), list(range(FRAMES)), device="cpu", resume=True,
                                options=SETTINGS.tracking_options(joint=False))
    assert report["options"]["mode"] == "sequential" and report["options"]["sequential_subtract"] is True
    s = run_serial(build_tasks([got], bones=list(BONES), mode="sequential"), SETTINGS)
    assert s["status"] == "complete" and s["frames_tracked"] == FRAMES * len(BONES), s
    (rec,) = s["task_records"]
    assert rec["mode"] == "sequential" and rec["sequential_subtract"] is True
    assert rec["sequential_subtract_note"] is None
    with Study.open(ref) as a, Study.open(got) as b:
        for bone in BONES:
            pa, pb = a.trial("walk").poses(bone)[:FRAMES], b.trial("walk").poses(bone)[:FRAMES]
            assert np.isfinite(pb).all(), bone
            np.testing.assert_array_equal(pb, pa, err_msg=bone)
        assert b.read_report("tracking", "walk")["options"]["sequential_subtract"] is True
    s = run_serial(build_tasks([split], bones=list(BONES), mode="sequential", split_bones=True), SETTINGS)
    assert s["status"] == "complete" and len(s["task_records"]) == 2
    for r in s["task_records"]:
        assert r["mode"] == "sequential" and r["sequential_subtract"] is False
        assert r["sequential_subtract_note"] == "on, but no other bone tracked: nothing to subtract"


def test_a_resumed_sequential_task_keeps_the_choice_that_ran(calibrated, tmp_path):
    """Frame 0 tracked with the neighbours not subtracted (--sequential-subtract off), then the batch
    run again with auto over frames 0-1: the task carries on with the choice its report recorded (off,
    where auto alone would subtract on these corrected frames), and its record says why."""
    folder = shutil.copytree(calibrated, tmp_path / "demo")
    tasks = build_tasks([folder], bones=list(BONES), mode="sequential")
    off = TaskSettings(device="cpu", confidence=False, frames=(0, 1),
                       options=(*OPTIONS, ("sequential_subtract", False)))
    (first,) = run_serial(tasks, off)["task_records"]
    assert first["sequential_subtract"] is False and first["frames_tracked"] == 2
    (again,) = run_serial(tasks, SETTINGS)["task_records"]
    assert again["status"] == "complete" and again["frames_resumed"] == 2 and again["frames_tracked"] == 2
    assert again["sequential_subtract"] is False
    assert again["sequential_subtract_note"].startswith("resumed: neighbours not subtracted, as the run "
                                                        "being resumed recorded")


def test_a_grouped_task_resuming_split_bones_tasks_searches_each_bone_alone(calibrated, tmp_path):
    """Frame 0 tracked by ``--split-bones`` tasks (each bone alone: reports walk.talus and
    walk.calcaneus, no walk.json), then the batch run again grouped over frames 0-1: the task carries
    on as the earlier frames were searched (not subtracted, where auto alone would subtract on these
    corrected frames), its record naming the tasks' reports."""
    folder = shutil.copytree(calibrated, tmp_path / "demo")
    split = build_tasks([folder], bones=list(BONES), mode="sequential", split_bones=True)
    first = TaskSettings(device="cpu", confidence=False, frames=(0, 1), options=OPTIONS)
    assert [r["frames_tracked"] for r in run_serial(split, first)["task_records"]] == [1, 1]
    grouped = build_tasks([folder], bones=list(BONES), mode="sequential")
    (again,) = run_serial(grouped, SETTINGS)["task_records"]
    assert again["status"] == "complete" and again["frames_resumed"] == 2 and again["frames_tracked"] == 2
    assert again["sequential_subtract"] is False
    assert again["sequential_subtract_note"] == (
        "resumed: neighbours not subtracted (auto), as the trial's earlier runs did: "
        "walk.calcaneus (one bone), walk.talus (one bone)")


def test_fresh_ranges_sharing_a_keyframe_are_not_resumed(calibrated, tmp_path):
    """A fresh ``talus batch --ranges`` run whose two ranges share a keyframe (both bones keyed at
    frame 1: ranges 1-0 and 1-2): the second range finds the keyframe tracked by the first, which is
    no resume of it; its record said 'resumed … as the trial's earlier runs did: walk.1-0'. Both
    ranges decide as new runs (auto: subtracted on these corrected frames), without a note."""
    folder = shutil.copytree(calibrated, tmp_path / "demo")
    with Study.open(folder, mode="w") as st:
        tr = st.trial("walk")
        for b in BONES:  # keyed at frame 1 only
            tr.clear_pose(b, 0)
            tr.record_pose(b, 1, np.load(folder / "poses" / f"{b}.npy")[1])
    tasks = build_tasks([folder], bones=list(BONES), mode="sequential", ranges=True, frames=(0, 3))
    assert [t.frames for t in tasks] == [(1, 0), (1, 2)]
    s = run_serial(tasks, TaskSettings(device="cpu", confidence=False, frames=(0, 3), options=OPTIONS))
    assert s["status"] == "complete", s
    for r in s["task_records"]:
        assert r["sequential_subtract"] is True, r
        assert r["sequential_subtract_note"] is None, r
