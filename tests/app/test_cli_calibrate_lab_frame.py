"""``talus calibrate`` and the lab frame: a warning on stderr and in the summary whenever the lab
frame is not the static cube's, ``--lab-frame object`` passed on, and the error of a cube frame
that cannot be labelled (the study unchanged). The calibration itself is replaced by stand-ins
(the session calibration and its errors are tested in tests/core/calibration)."""

import json
from types import SimpleNamespace

import pytest

import core.calibration.session as cs
import core.io.calibration_session as io_session
import core.study.calibrations as calibrations
from app.cli import main as talus

WARNING = ("the session has no static cube15 frame: the lab frame is the spiral33's first labelled frame, "
           "an arbitrary pose of a hand-held object (record a static object frame to fix the lab frame)")


def _report(warnings):
    cam = {"name": "cam1", "fx_px": 2000.0, "sid_mm": 1200.0, "source_mm": [0.0, 0.0, 0.0], "std": {}}
    dist = {"model": "poly(4,4)", "residuals": {"mm": {"rms": 0.02}}}
    return {"rig": [cam], "bundle": {"rms_px": 0.05}, "n_frames_labelled": 9, "frames": [{}] * 9,
            "cameras": [{"name": "cam1", "distortion": dist, "lattice_check": None}],
            "error_volume": {"rms_mm": 0.02}, "notes": ["lab frame: the spiral33 in its first frame"],
            "lab_frame": {"defined_by": "object", "object": "spiral33", "frame": ["a.tif", "b.tif"]},
            "warnings": list(warnings)}


@pytest.fixture
def setup(tmp_path, monkeypatch):
    from core.study import Study

    Study.create(tmp_path / "study").close()
    (tmp_path / "session").mkdir()
    monkeypatch.setattr(io_session, "read_session", lambda path: SimpleNamespace(path=path))
    calls = {}

    def save(study, cal, **kw):
        calls["saved"] = True
        return SimpleNamespace(name="session.v1", folder=tmp_path / "study" / "v1", trials=())

    monkeypatch.setattr(calibrations, "save_session_calibration", save)
    return tmp_path, calls


def test_warning_when_the_lab_frame_is_not_the_cube(setup, monkeypatch, capsys):
    tmp, calls = setup

    def calibrate(session, **kw):
        calls["kw"] = kw
        return SimpleNamespace(report=_report([WARNING]))

    monkeypatch.setattr(cs, "calibrate_session", calibrate)
    rc = talus(["calibrate", str(tmp / "session"), "--study", str(tmp / "study"), "--quiet",
                "--lab-frame", "object"])
    out = capsys.readouterr()
    assert rc == 0, out.err
    assert calls["kw"]["lab_frame"] == "object" and calls["saved"]
    assert f"talus calibrate: WARNING: {WARNING}" in out.err
    doc = json.loads(out.out)
    assert doc["warnings"] == [WARNING] and doc["lab_frame"]["defined_by"] == "object"


def test_no_warning_with_the_cube(setup, monkeypatch, capsys):
    tmp, calls = setup
    rep = _report([])
    rep["lab_frame"] = {"defined_by": "static", "object": "cube15", "frame": ["a.tif", "b.tif"]}

    def calibrate(session, **kw):
        calls["kw"] = kw
        return SimpleNamespace(report=rep)

    monkeypatch.setattr(cs, "calibrate_session", calibrate)
    assert talus(["calibrate", str(tmp / "session"), "--study", str(tmp / "study"), "--quiet"]) == 0
    out = capsys.readouterr()
    assert calls["kw"]["lab_frame"] == "static"
    assert "WARNING" not in out.err and json.loads(out.out)["warnings"] == []


def test_unlabelled_cube_leaves_the_study_unchanged(setup, monkeypatch, capsys):
    tmp, calls = setup

    def calibrate(session, **kw):
        raise cs.SessionError("beads", "session/cam1/cube/0000.tif (cube15 frame 0)",
                              "the static cube15 frame was recorded but could not be labelled (no "
                              "consistent labelling); it defines the lab frame",
                              "record the cube15 again, or calibrate with --lab-frame object")

    monkeypatch.setattr(cs, "calibrate_session", calibrate)
    before = (tmp / "study" / "study.json").read_bytes()
    assert talus(["calibrate", str(tmp / "session"), "--study", str(tmp / "study"), "--quiet"]) == 1
    err = capsys.readouterr().err
    assert "beads: session/cam1/cube/0000.tif (cube15 frame 0): the static cube15 frame" in err
    assert "--lab-frame object" in err
    assert "saved" not in calls and (tmp / "study" / "study.json").read_bytes() == before
    with pytest.raises(SystemExit):
        talus(["calibrate", str(tmp / "session"), "--study", str(tmp / "study"), "--lab-frame", "cube"])
