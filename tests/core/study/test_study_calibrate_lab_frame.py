"""``calibrate_study`` passes the lab-frame choice to the session calibration: ``"static"`` by
default (as ``talus calibrate``), ``"object"`` when asked, the calibration's warnings kept with
what is saved, and a wrong value refused by the session calibration before anything is read or
saved. The calibration itself is replaced by stand-ins (the session calibration and its lab
frame are tested in tests/core/calibration)."""

from types import SimpleNamespace

import pytest

import core.calibration.session as cs
import core.io.calibration_session as io_session
import core.study.calibrations as calibrations
from core.study import Study
from core.study.calibrations import calibrate_study

WARNING = "the lab frame is the spiral33's first labelled frame, not the static cube15's"


def _state(folder):
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.fixture
def setup(tmp_path, monkeypatch):
    Study.create(tmp_path / "study").close()
    calls = {}

    def read(path):
        calls["read"] = path
        return SimpleNamespace(path=path)

    def save(study, cal, **kw):
        calls["saved"] = cal, kw
        return SimpleNamespace(name="session.v1", trials=())

    monkeypatch.setattr(io_session, "read_session", read)
    monkeypatch.setattr(calibrations, "save_session_calibration", save)
    return tmp_path, calls


def _stand_in(calls, monkeypatch):
    def calibrate(session, **kw):
        calls["kw"] = kw
        warnings = [WARNING] if kw["lab_frame"] == "object" else []
        return SimpleNamespace(report={"warnings": warnings})

    monkeypatch.setattr(cs, "calibrate_session", calibrate)


def test_lab_frame_object_is_passed_on_and_its_warning_kept(setup, monkeypatch):
    tmp, calls = setup
    _stand_in(calls, monkeypatch)
    with Study.open(tmp / "study", mode="w") as st:
        saved, cal = calibrate_study(st, tmp / "session", lab_frame="object", series="day1")
    assert calls["kw"]["lab_frame"] == "object" and saved.name == "session.v1"
    assert calls["saved"][0] is cal and calls["saved"][1]["series"] == "day1"
    assert cal.report["warnings"] == [WARNING]


def test_lab_frame_is_the_static_object_by_default(setup, monkeypatch):
    tmp, calls = setup
    _stand_in(calls, monkeypatch)
    with Study.open(tmp / "study", mode="w") as st:
        _, cal = calibrate_study(st, tmp / "session")
    assert calls["kw"]["lab_frame"] == "static" and cal.report["warnings"] == []


def test_a_wrong_lab_frame_is_refused_and_nothing_saved(setup):
    tmp, calls = setup
    before = _state(tmp / "study")
    with (Study.open(tmp / "study", mode="w") as st,
          pytest.raises(ValueError, match="lab_frame: expected one of")):
        calibrate_study(st, tmp / "session", lab_frame="cube")  # the real session calibration says so
    assert "saved" not in calls and _state(tmp / "study") == before
