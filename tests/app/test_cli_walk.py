"""What a lab technician trips over walking the day with ``talus`` (demo, calibrate, import, track,
export, report): messages on stderr that say what happened and what to do, files not silently
overwritten, arguments given as the file inside a folder. Small studies on Warp's CPU device."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from app.cli import EXIT_NOTHING_DONE
from app.cli import main as talus
from tests.app._helpers import lab_collection, small_demo


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    return small_demo(tmp_path_factory.mktemp("demo") / "study")


@pytest.fixture
def study(demo, tmp_path):
    return shutil.copytree(demo, tmp_path / "study")


def test_track_without_keyframes_says_why_and_what_to_do_on_stderr(study, capsys):
    """A bone with no keyframe: the JSON's 'stopped' said why, stderr said nothing (exit 4)."""
    from core.study import Study

    with Study.open(study, mode="w") as st:
        for bone in st.trial("walk").bones:
            st.trial("walk").clear_pose(bone, 0)  # the demo's frame-0 keyframes gone
    rc = talus(["track", str(study), "--trial", "walk", "--bones", "talus", "--frames", "0:1",
                "--device", "cpu", "--quiet"])
    out = capsys.readouterr()
    assert rc == EXIT_NOTHING_DONE
    assert "no keyframe" in json.loads(out.out)["stopped"]["talus"]
    lines = out.err.splitlines()
    assert any(ln.startswith("talus track: talus not tracked: no keyframe") and "Mark keyframe" in ln
               and "record_pose" in ln for ln in lines), out.err
    assert lines[-1] == "talus track: nothing was tracked (exit status 4)"


def test_frames_outside_the_trial_name_its_length(study, capsys):
    assert talus(["track", str(study), "--trial", "walk", "--frames", "5:9", "--quiet"]) == 1
    assert "'5:9' is not a non-empty range of the trial's 2 frames (0:2" in capsys.readouterr().err


def test_export_default_names_never_collide_and_match_the_dialog(study, tmp_path, capsys):
    """'csv' and 'xromm-csv' both wrote exports/walk.csv: the second silently replaced the first.
    Every format now has its own default name, the one File > Export... proposes."""
    from core.study.exports import available_formats, default_path

    written = {}
    for fmt in ("csv", "xromm-csv", "tra", "tra-talus", "csv-6dof", "json", "mot", "trc", "tfm"):
        assert talus(["export", str(study), "--trial", "walk", "--format", fmt]) == 0
        written[fmt] = json.loads(capsys.readouterr().out)["files"]
    assert written["csv"] == [str(study / "exports" / "walk_csv.csv")]
    assert written["xromm-csv"] == [str(study / "exports" / "walk_xromm-csv.csv")]
    assert written["tra"] == [str(study / "exports" / "walk_tra-autoscoper.tra")]  # Autoscoper's frame
    assert written["tfm"][0].startswith(str(study / "exports" / "walk_tfm") + "/")
    files = [f for fs in written.values() for f in fs]
    assert len(set(files)) == len(files)
    assert (study / "exports" / "walk_csv.csv").read_text().startswith("frame,")  # not XMALab's
    assert default_path(study, "walk", "xromm-csv") == study / "exports" / "walk_xromm-csv.csv"
    assert len({default_path(study, "walk", f) for f in available_formats()}) == len(available_formats())


def test_export_to_an_existing_folder_puts_the_default_name_inside(study, tmp_path, capsys):
    """--out DIR (a folder) failed with '[Errno 21] Is a directory' naming a temporary file."""
    (tmp_path / "out").mkdir()
    assert talus(["export", str(study), "--trial", "walk", "--format", "csv-6dof",
                  "--out", str(tmp_path / "out")]) == 0
    assert json.loads(capsys.readouterr().out)["files"] == [str(tmp_path / "out" / "walk_csv-6dof.csv")]
    assert (tmp_path / "out" / "walk_csv-6dof.csv").is_file()


@pytest.mark.parametrize("calibration, expect", [
    ({"error": "beads: cam1/cube/0000.tif (cube15 frame 0): the static cube15 frame was recorded but "
               "could not be labelled"},
     "talus demo: WARNING: the study could not be calibrated from its session, so its trial uses the "
     "generator's rig without correction: beads: cam1/cube/0000.tif"),
    ({"skipped": "128-pixel images are too coarse to calibrate"},
     "talus demo: not calibrated: 128-pixel images are too coarse to calibrate"),
    ({"calibration": "session.v1", "reprojection_rms_px": 0.05}, None),
])
def test_demo_says_on_stderr_when_its_study_is_not_calibrated(monkeypatch, tmp_path, capsys, calibration,
                                                              expect):
    """The demo's calibration failure (the 256^2 demo's cube frame) was only in the JSON summary."""
    import sys
    import types

    def make_demo_study(out_dir, *, progress, cancel, **options):
        return {"status": "complete", "calibration_session": "calibration_session",
                "calibration": calibration}

    fake = types.SimpleNamespace(__name__="core.synthetic.demo", make_demo_study=make_demo_study)
    monkeypatch.setitem(sys.modules, "core.synthetic.demo", fake)
    assert talus(["demo", "--out", str(tmp_path), "--frames", "2", "--no-gui"]) == 0
    err = capsys.readouterr().err
    if expect is None:
        assert "calibrat" not in err
    else:
        assert expect in err
        if "WARNING" in expect:
            assert f"talus calibrate {tmp_path / 'calibration_session'} --study {tmp_path}" in err


def test_calibrate_refuses_unknown_trials_before_calibrating(study, tmp_path, capsys, monkeypatch):
    """--trials with a misspelt name was refused only after the whole calibration (minutes)."""
    import core.study.calibrations as calibrations

    def never(*a, **k):
        raise AssertionError("calibrated before checking --trials")

    monkeypatch.setattr(calibrations, "calibrate_study", never)
    (tmp_path / "session").mkdir()
    argv = ["calibrate", str(tmp_path / "session"), "--study", str(study), "--trials", "walk,wlak"]
    assert talus(argv) == 1
    assert "--trials: the study has no trial 'wlak' (has walk" in capsys.readouterr().err


def test_a_calibration_no_trial_uses_says_how_to_use_it(study, capsys):
    """talus calibrate's default (--trials series) leaves an imported study's trials on their rig:
    the JSON said trials: [] and nothing else. The note names the command that points them at it,
    and that command does."""
    from types import SimpleNamespace

    from app.commands.calibrate import unused_note
    from core.study import Study

    saved = SimpleNamespace(name="rig", trials=())
    note = unused_note(saved, {"walk": "rig"}, study)
    assert note == (f"no trial uses rig yet (walk uses rig); point them at it with 'talus study "
                    f"use-calibration {study} rig' (--trials a,b for some)")
    assert unused_note(SimpleNamespace(name="session.v1", trials=("walk",)), {"walk": "rig"}, study) is None
    with Study.open(study, mode="w") as st:
        folder = st.folder
        st.add_calibration("other", [folder / "rig" / "cam01.txt", folder / "rig" / "cam02.txt"])
    assert talus(["study", "use-calibration", str(study), "other"]) == 0
    out = capsys.readouterr()
    assert json.loads(out.out)["trials"] == {"walk": {"before": "rig", "after": "other"}}
    assert "walk now uses other" in out.err
    with Study.open(study) as st:
        assert st.trial("walk").calibration == "other"
    assert talus(["study", "use-calibration", str(study), "nope"]) == 1
    assert "no calibration named 'nope'" in capsys.readouterr().err
    assert talus(["study", "use-calibration", str(study), "rig", "--trials", "run"]) == 1
    assert "--trials: the study has no trial 'run' (has walk)" in capsys.readouterr().err


@pytest.fixture
def lab(demo, tmp_path):
    """A collection folder as a lab has it: two frame folders, two MayaCam files, one CT per bone."""
    return lab_collection(demo, tmp_path / "lab")


def test_import_bones_named_as_their_files_keep_their_files(lab, tmp_path, capsys):
    """--bones talus,calcaneus over ct/calcaneus.mha and ct/talus.mha (scanned alphabetically) gave
    the talus the calcaneus's CT and the calcaneus the talus's."""
    from core.study import Study

    assert talus(["import", str(lab), "--out", str(tmp_path / "s1"), "--bones", "talus,calcaneus"]) == 0
    err = capsys.readouterr().err
    assert f"bone talus from {lab / 'ct' / 'talus.mha'}" in err
    with Study.open(tmp_path / "s1") as st:
        doc = st._doc
    files = {b: Path(doc["volumes"][doc["bones"][b]["volume"]]["path"]).name for b in doc["bones"]}
    assert files == {"talus": "talus.mha", "calcaneus": "calcaneus.mha"}
    # other names: in the scan's (file) order, and said so
    assert talus(["import", str(lab), "--out", str(tmp_path / "s2"), "--bones", "a,b"]) == 0
    err = capsys.readouterr().err
    assert f"bone a from {lab / 'ct' / 'calcaneus.mha'}" in err
    assert f"bone b from {lab / 'ct' / 'talus.mha'}" in err


def test_import_names_a_file_of_the_wrong_kind(demo, tmp_path, capsys):
    """A file that is no project was 'no folder at FILE (or an Autoscoper .cfg file)'."""
    assert talus(["import", str(demo / "rig" / "cam01.txt"), "--out", str(tmp_path / "s")]) == 1
    err = capsys.readouterr().err
    assert "cam01.txt is a file; expected a collection folder, an Autoscoper .cfg or an XMALab .xma" in err
    assert talus(["import", str(demo / "study.json"), "--out", str(tmp_path / "s")]) == 1
    assert "study.json is a Talus study's manifest: the study exists already" in capsys.readouterr().err
    assert talus(["import", str(tmp_path / "nowhere")]) == 1
    assert "no folder at" in capsys.readouterr().err and not (tmp_path / "s").exists()


def test_a_study_or_session_manifest_stands_for_its_folder(study, tmp_path, capsys, monkeypatch):
    """'talus export STUDY/study.json' was 'no study folder at .../study.json'."""
    import core.study.calibrations as calibrations

    assert talus(["export", str(study / "study.json"), "--trial", "walk", "--format", "json"]) == 0
    assert json.loads(capsys.readouterr().out)["files"] == [str(study / "exports" / "walk_json.json")]
    seen = []

    def calibrate_study(st, session, **options):
        seen.append(session)
        raise ValueError("stop here")

    monkeypatch.setattr(calibrations, "calibrate_study", calibrate_study)
    (tmp_path / "session").mkdir()
    (tmp_path / "session" / "session.json").write_text("{}")
    assert talus(["calibrate", str(tmp_path / "session" / "session.json"), "--study", str(study),
                  "--quiet"]) == 1
    assert seen == [tmp_path / "session"] and "stop here" in capsys.readouterr().err


def test_gui_takes_a_study_manifest_for_its_folder(study, monkeypatch):
    import sys
    import types

    shown = []
    fake = types.SimpleNamespace(__name__="app.main_window", run_gui=lambda demo: shown.append(demo) or 0)
    monkeypatch.setitem(sys.modules, "app.main_window", fake)
    monkeypatch.setenv("QT_QPA_PLATFORM", "offscreen")
    assert talus(["gui", "--demo", str(study / "study.json")]) == 0
    assert shown == [study]


def test_sample_wrist_finds_the_shared_data_from_any_working_folder(tmp_path, monkeypatch):
    """The default --data was '../shared/data/autoscoper_wrist' of the working folder: from
    anywhere but the source folder, 'talus sample wrist' said the sample was missing."""
    from app.commands.sample import default_wrist_folder

    monkeypatch.delenv("TALUS_SAMPLE_DATA", raising=False)
    monkeypatch.chdir(tmp_path)
    root = Path(__file__).resolve().parents[2]  # the source folder
    assert default_wrist_folder() == root.parent / "shared" / "data" / "autoscoper_wrist"
    monkeypatch.setenv("TALUS_SAMPLE_DATA", str(tmp_path / "data"))
    assert default_wrist_folder() == tmp_path / "data" / "autoscoper_wrist"


def test_a_resumed_track_times_its_eta_from_the_new_frames(monkeypatch):
    """'talus track --resume' over 0:2 with frame 0 done said 'ETA 0.8 s' at 1/2 before a frame of
    a minute: the frame taken back from the journal counted as work done in 0.8 s."""
    import io
    from types import SimpleNamespace

    from app.commands import _shared
    from app.commands._shared import Progress
    from app.commands.track import _Bar

    clock = [0.0]
    monkeypatch.setattr(_shared.time, "perf_counter", lambda: clock[0])
    out = io.StringIO()
    bar = _Bar(Progress("track", stream=out, in_place=False), resumed=frozenset({("talus", 0), ("talus", 1)}))
    fr = lambda f: SimpleNamespace(bone="talus", frame=f, score=0.5, flags=(), timing=None)  # noqa: E731
    clock[0] = 0.8
    bar(1, 6, fr(0))  # taken back: no ETA
    bar(2, 6, fr(1))
    clock[0] += 60.0
    bar(3, 6, fr(2))  # the first new frame: a minute
    clock[0] += 60.0
    bar(5, 6, fr(4))  # frame 3 was a hand-set pose (not reported): not this run's work
    lines = out.getvalue().splitlines()
    assert "ETA" not in lines[0] and "ETA" not in lines[1]
    assert "3/6" in lines[2] and "ETA 3 min 00 s" in lines[2]  # 3 frames left at a minute each
    assert "5/6" in lines[3] and "ETA 1 min 00 s" in lines[3]


def test_demo_says_it_builds_the_scene_and_times_its_eta_from_the_first_frame(monkeypatch, tmp_path,
                                                                              capsys):
    """37 s of silence before 'frame 1/3' at 128 px on the 2-core CPU, then 'ETA 1 min 14 s' for
    two frames that took no time: the scene's set-up was counted as the first frame's."""
    import sys
    import types

    from app.commands import _shared

    clock = [0.0]
    monkeypatch.setattr(_shared.time, "perf_counter", lambda: clock[0])

    def make_demo_study(out_dir, *, n_frames, progress, cancel, **options):
        clock[0] += 37.0  # the scene
        for i in range(n_frames):
            clock[0] += 1.0
            progress(i + 1, n_frames)
        return {"status": "complete"}

    fake = types.SimpleNamespace(__name__="core.synthetic.demo", make_demo_study=make_demo_study)
    monkeypatch.setitem(sys.modules, "core.synthetic.demo", fake)
    assert talus(["demo", "--out", str(tmp_path), "--frames", "4", "--no-gui"]) == 0
    lines = capsys.readouterr().err.splitlines()
    assert lines[0].startswith(f"talus demo: writing the synthetic study to {tmp_path}; building its bones")
    frames = [ln for ln in lines if "frame " in ln and "/4" in ln]
    assert "ETA" not in frames[0]
    assert "frame 2/4" in frames[1] and "ETA 2.0 s" in frames[1]  # 2 frames left at 1 s each


def test_track_says_what_it_does_before_the_first_frame(study, capsys):
    """53 s passed before the first line of a one-bone 128 px track on the 2-core CPU."""
    # no bone above the threshold: nothing registered (the line comes before any work)
    assert talus(["track", str(study), "--trial", "walk", "--bones", "talus", "--frames", "1:2",
                  "--device", "cpu", "--threshold", "99999"]) == EXIT_NOTHING_DONE
    lines = capsys.readouterr().err.splitlines()
    first = next(ln for ln in lines if ln.startswith("talus track:"))
    assert first == ("talus track: trial walk, frames 1-1: loading the bones' CTs, then the first frame "
                     "(it searches wider: the longest)")


def test_the_readme_synopsis_names_every_option_of_the_commands():
    """The README's `talus` synopsis had lost options (report and study use-calibration missing,
    export --frame/--camera, track --threshold, import --hu-offset; batch --joint, --metric,
    --threshold, --max-uncertainty, --no-trajectory-check). Every long option of every command
    (one of an option's names) must be in its lines."""
    import argparse
    import re

    from app.cli import build_parser

    readme = (Path(__file__).resolve().parents[2] / "README.md").read_text(encoding="utf-8")
    block = readme.split("## The `talus` command", 1)[1].split("```text", 1)[1].split("```", 1)[0]
    lines: dict[str, str] = {}
    command = None
    for line in block.splitlines():
        m = re.match(r"talus (\w+)", line)
        command = m.group(1) if m else command
        if command:
            lines[command] = lines.get(command, "") + line + "\n"
    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))

    def options(parser):
        for a in parser._actions:
            if isinstance(a, argparse._SubParsersAction):
                for p in a.choices.values():
                    yield from options(p)
            elif a.help != argparse.SUPPRESS and any(o.startswith("--") and o != "--help"
                                                     for o in a.option_strings):
                yield [o for o in a.option_strings if o.startswith("--")]

    missing = {}
    for name, parser in sub.choices.items():
        text = lines.get(name, "")
        gone = [names[0] for names in options(parser)
                if not any(re.search(re.escape(o) + r"(?![\w-])", text) for o in names)]
        if not text or gone:
            missing[name] = gone or "the command"
    assert not missing, missing


def test_moving_a_trial_with_poses_to_a_calibration_in_another_lab_frame_warns(study, capsys):
    """After 'talus calibrate --lab-frame object --trials all' on the demo, its keyframes (recorded
    in the generator's lab frame) drew the tibia across the image, and nothing said why."""
    from core.study import Study
    from core.study.calibrations import lab_frame_note, source_shift_mm

    with Study.open(study, mode="w") as st:
        rig = [st.folder / "rig" / "cam01.txt", st.folder / "rig" / "cam02.txt"]
        st.add_calibration("same", rig)
        st.add_calibration("swapped", rig[::-1])  # each source elsewhere: as a moved lab frame
        assert source_shift_mm(st, "rig", "same") == [0.0, 0.0]
        assert min(source_shift_mm(st, "rig", "swapped")) > 100
        assert lab_frame_note(st, "walk", "rig", "same") is None
    assert talus(["study", "use-calibration", str(study), "swapped"]) == 0
    out = capsys.readouterr()
    (warning,) = json.loads(out.out)["warnings"]
    assert warning.startswith("trial 'walk' moved from calibration rig to swapped, whose cameras see its "
                              "recorded poses up to ")
    assert "mm (at the bone) from where rig's do (the X-ray sources lie " in warning
    assert "4 recorded poses (4 of them keyframes) are in rig's lab frame" in warning  # frame 0's
    assert f"talus study use-calibration: WARNING: {warning}" in out.err
    assert talus(["study", "use-calibration", str(study), "rig"]) == 0  # back: warned again
    assert "moved from calibration swapped to rig" in capsys.readouterr().err
    with Study.open(study, mode="w") as st:
        for bone in st.trial("walk").bones:
            st.trial("walk").clear_pose(bone, 0)
    assert talus(["study", "use-calibration", str(study), "swapped"]) == 0  # nothing recorded
    assert json.loads(capsys.readouterr().out)["warnings"] == []


def test_the_trial_report_carries_its_calibrations_warnings(study, tmp_path, capsys):
    """A calibration whose lab frame is the spiral's (not the cube's) warns in talus calibrate and in
    its saved report; the trial report, made to be shared, said nothing of it."""
    from core.study import Study
    from core.study.calibrations import use_calibration

    version = study / "calibrations" / "session" / "v1"
    (version / "report").mkdir(parents=True)
    (version / "calibration.json").write_text(json.dumps({"quality": {"method": "bundle adjustment",
                                                                      "rms_px": 0.05}}))
    warning = "the lab frame is the spiral33's first labelled frame, not the static cube15's"
    (version / "report" / "report.json").write_text(json.dumps({"warnings": [warning]}))
    doc = json.loads((study / "study.json").read_text())
    doc["settings"]["calibration_files"] = {"session.v1": {"series": "session", "version": 1,
                                                           "folder": "calibrations/session/v1"}}
    (study / "study.json").write_text(json.dumps(doc))
    with Study.open(study, mode="w") as st:
        st.add_calibration("session.v1", [study / "rig" / "cam01.txt", study / "rig" / "cam02.txt"])
        use_calibration(st, "walk", "session.v1")
    assert talus(["report", str(study), "--trial", "walk", "--out", str(tmp_path / "r.html")]) == 0
    page = (tmp_path / "r.html").read_text(encoding="utf-8")
    assert "warning: the lab frame is the spiral33&#x27;s first labelled frame" in page


def test_names_lists_take_spaces_after_the_commas(study, tmp_path, capsys):
    """--bones 'talus, calcaneus' was refused: "trial 'walk' has no bone ' calcaneus'"."""
    from app.commands._shared import names

    assert names("talus, calcaneus ,") == ["talus", "calcaneus"] and names(None) is None
    assert talus(["export", str(study), "--trial", "walk", "--format", "csv-6dof", "--bones",
                  "talus, calcaneus", "--out", str(tmp_path / "x.csv")]) == 0
    assert (tmp_path / "x.csv").read_text().splitlines()[0].startswith("frame,talus_tx_mm")
    capsys.readouterr()
    assert talus(["track", str(study), "--trial", "walk", "--bones", "talus, calcaneus", "--frames", "1:2",
                  "--device", "cpu", "--threshold", "99999", "--quiet"]) == EXIT_NOTHING_DONE
    assert sorted(json.loads(capsys.readouterr().out)["stopped"]) == ["calcaneus", "talus"]


def test_export_says_how_many_frames_have_a_pose_and_warns_when_none(study, tmp_path, capsys):
    """An export of a trial without poses wrote a file of NaN and said 'wrote 1 file(s)'."""
    from core.study import Study

    assert talus(["export", str(study), "--trial", "walk", "--format", "csv-6dof"]) == 0
    out = capsys.readouterr()
    doc = json.loads(out.out)
    assert doc["frames"] == 2 and doc["frames_with_pose"] == {"tibia": 1, "talus": 1, "calcaneus": 1,
                                                              "metatarsal2": 1}
    assert "frames with a pose, of 2: tibia 1, talus 1, calcaneus 1, metatarsal2 1" in out.err
    assert "WARNING" not in out.err
    with Study.open(study, mode="w") as st:
        for bone in st.trial("walk").bones:
            st.trial("walk").clear_pose(bone, 0)
    assert talus(["export", str(study), "--trial", "walk", "--format", "csv-6dof", "--bones", "talus"]) == 0
    out = capsys.readouterr()
    assert json.loads(out.out)["frames_with_pose"] == {"talus": 0}
    assert "WARNING: no bone has a pose in trial 'walk'" in out.err


@pytest.mark.parametrize("gpus, argv, expect", [
    (0, ["track", "{s}", "--trial", "walk", "--device", "cuda"],
     "--device cuda: no CUDA GPU found on this machine"),
    (1, ["track", "{s}", "--trial", "walk", "--device", "cuda:3"],
     "--device cuda:3: this machine has 1 CUDA GPU(s), cuda:0 to cuda:0"),
    (0, ["track", "{s}", "--trial", "walk", "--device", "gpu"], "--device: expected cpu, cuda or cuda:N"),
    (0, ["demo", "--out", "{t}", "--device", "cuda", "--no-gui"], "--device cuda: no CUDA GPU found"),
    (0, ["bench", "drr", "--quick", "--device", "cuda"], "--device cuda: no CUDA GPU found"),
    (0, ["batch", "{s}", "--workers", "0", "--device", "cuda"], "--device cuda: no CUDA GPU found"),
    (0, ["batch", "{s}", "--workers", "0", "--device", "gpu"], "--device: expected cpu, cuda or cuda:N"),
    (0, ["batch", "{s}", "--scheduler", "tcp://head:8786", "--device", "gpu"],
     "--device: expected cpu, cuda or cuda:N"),
])
def test_a_device_this_machine_lacks_is_named_before_any_work(study, tmp_path, capsys, monkeypatch, gpus,
                                                             argv, expect):
    """'--device cuda' without a GPU was 'RuntimeError: "cuda" device requested but CUDA is not
    supported by the hardware or driver (run talus --debug ... for the traceback)', as for a bug."""
    import warp as wp

    monkeypatch.setattr(wp, "init", lambda: None)
    monkeypatch.setattr(wp, "get_cuda_device_count", lambda: gpus)
    assert talus([a.format(s=study, t=tmp_path / "demo") for a in argv]) == 1
    err = capsys.readouterr().err
    assert expect in err and "Traceback" not in err and "--debug" not in err
    assert not (tmp_path / "demo").exists()


def test_demo_refuses_a_folder_it_would_damage(study, tmp_path, monkeypatch, capsys):
    """'talus demo --out' a lab's study (or the working folder) replaced its study.json and deleted
    its results/ (the pose journals)."""
    import sys
    import types

    made = []
    fake = types.SimpleNamespace(__name__="core.synthetic.demo",
                                 make_demo_study=lambda out, **k: made.append(out) or {"status": "complete"})
    monkeypatch.setitem(sys.modules, "core.synthetic.demo", fake)
    journals = sorted((study / "results").rglob("*.jsonl"))
    (study / "summary.json").unlink()  # a lab's study: no demo summary, its own name
    doc = json.loads((study / "study.json").read_text(encoding="utf-8"))
    (study / "study.json").write_text(json.dumps({**doc, "name": "gait lab"}), encoding="utf-8")
    assert talus(["demo", "--out", str(study), "--no-gui"]) == 1
    assert "holds a study that is not a demo" in capsys.readouterr().err
    assert sorted((study / "results").rglob("*.jsonl")) == journals and made == []
    (tmp_path / "work").mkdir()
    (tmp_path / "work" / "notes.txt").write_text("mine")
    assert talus(["demo", "--out", str(tmp_path / "work"), "--no-gui", "--regenerate"]) == 1
    assert "is not empty and holds no demo" in capsys.readouterr().err and made == []
    (tmp_path / "file").write_text("x")
    assert talus(["demo", "--out", str(tmp_path / "file"), "--no-gui"]) == 1
    (tmp_path / "empty").mkdir()
    assert talus(["demo", "--out", str(tmp_path / "empty"), "--no-gui"]) == 0  # new or empty: written
    (tmp_path / "old").mkdir()
    (tmp_path / "old" / "summary.json").write_text(json.dumps({"format": "talus-synthetic-study",
                                                               "status": "cancelled"}))
    assert talus(["demo", "--out", str(tmp_path / "old"), "--no-gui"]) == 0  # an earlier demo: rebuilt
    assert made == [tmp_path / "empty", tmp_path / "old"]
    (tmp_path / "old" / "results" / "walk" / "poses").mkdir(parents=True)
    (tmp_path / "old" / "results" / "walk" / "poses" / "talus.jsonl").write_text("")
    assert talus(["demo", "--out", str(tmp_path / "old"), "--no-gui", "--regenerate"]) == 0
    assert "rebuilding the demo study in" in capsys.readouterr().err  # its tracked poses go


def test_demo_rebuilds_a_demo_that_stopped_before_its_summary(demo, tmp_path, monkeypatch, capsys):
    """A Ctrl-C during the demo's calibration raises out of the generator after the study is
    written and before summary.json (written last); a killed run leaves its rig and frames. Both
    folders were refused as 'a study that is not a demo' / 'holds no demo', --regenerate too."""
    import sys
    import types

    made = []
    fake = types.SimpleNamespace(__name__="core.synthetic.demo",
                                 make_demo_study=lambda out, **k: made.append(out) or {"status": "complete"})
    monkeypatch.setitem(sys.modules, "core.synthetic.demo", fake)
    stopped = shutil.copytree(demo, tmp_path / "stopped")
    (stopped / "summary.json").unlink()  # the demo's own study (named talus-demo), no summary
    assert talus(["demo", "--out", str(stopped), "--no-gui"]) == 0
    killed = tmp_path / "killed"  # before the study: the demo's rig, imaging, volumes, frames
    for part in ("rig", "imaging", "frames"):
        shutil.copytree(demo / part, killed / part)
    assert talus(["demo", "--out", str(killed), "--no-gui", "--regenerate"]) == 0
    assert made == [stopped, killed]
    (killed / "rig" / "rig.json").write_text("{}")  # a lab's rig folder: refused
    assert talus(["demo", "--out", str(killed), "--no-gui"]) == 1
    assert "is not empty and holds no demo" in capsys.readouterr().err and len(made) == 2


def test_a_calibration_of_the_same_lab_frame_whose_sources_moved_does_not_warn(study, capsys):
    """The warning went by the X-ray sources alone (over 2 mm): a DLT's sources lie 2-4 mm rms (up to
    10) from a bundle adjustment's of the same lab frame (resources/benchmarks/calibration_study.json),
    so moving an imported study's trial to its first 'talus calibrate' said its keyframes were in
    another lab frame. It now goes by where the cameras see the recorded poses."""
    import numpy as np

    from core.geometry import Camera
    from core.geometry.mayacam import write_mayacam
    from core.study import Study
    from core.study.calibrations import lab_frame_note, pose_shift_mm, source_shift_mm

    with Study.open(study, mode="w") as st:
        poses = st.trial("walk").poses(st.trial("walk").bones[0])[:1]
        files = []
        for cam in st.rig("rig"):  # each source 6 mm farther back along its axis, the focal length
            z = float(cam.project(poses[0, :3, 3], return_depth=True)[1])  # scaled at the talus
            K = cam.K.copy()
            K[:2, :2] *= (z + 6.0) / z
            moved = Camera(K=K, R=cam.R, t=cam.t + np.array([0.0, 0.0, 6.0]), width=cam.width,
                           height=cam.height, pixel_size=cam.pixel_size, name=cam.name)
            files.append(st.folder / f"{cam.name}_moved.txt")
            write_mayacam(moved, files[-1])
        st.add_calibration("refit", files)
        assert min(source_shift_mm(st, "rig", "refit")) > 5.9
        assert pose_shift_mm(st, "rig", "refit", poses) < 0.01
        assert pose_shift_mm(st, "rig", "refit", st.trial("walk").poses("calcaneus")[:1]) < 1.0
        assert lab_frame_note(st, "walk", "rig", "refit") is None
    assert talus(["study", "use-calibration", str(study), "refit"]) == 0
    assert json.loads(capsys.readouterr().out)["warnings"] == []
