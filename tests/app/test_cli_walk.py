"""What a lab technician trips over walking the day with ``talus`` (demo, calibrate, import, track,
export, report): messages on stderr that say what happened and what to do, files not silently
overwritten, arguments given as the file inside a folder. Small studies on Warp's CPU device."""

from __future__ import annotations

import json
import shutil

import pytest

from app.cli import EXIT_NOTHING_DONE
from app.cli import main as talus


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    from core.synthetic import make_demo_study

    out = tmp_path_factory.mktemp("demo") / "study"
    make_demo_study(out, n_frames=2, pixels=48, spacing=3.0, tissue_spacing=6.0, device="cpu",
                    calibration_session=False)
    return out


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
