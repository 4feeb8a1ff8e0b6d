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
