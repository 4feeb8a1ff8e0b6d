"""``talus calibrate``: a session saved into a study, bad input, Ctrl-C (the study unchanged)."""

import json
import shutil

import pytest

from app.cli import main as talus
from app.commands.calibrate import parse_model


def main(argv):
    return talus(["calibrate", *argv])


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    """The run's shared 384 px calibration session (the wizard walk's; read only)."""
    from tests.app._calibration_session import calibration_session

    return calibration_session(tmp_path_factory)


@pytest.fixture
def study(tmp_path):
    from core.study import Study

    Study.create(tmp_path / "study").close()
    return tmp_path / "study"


def test_parse_model():
    assert parse_model(None) == "auto" and parse_model(["tps"]) == "tps"
    assert parse_model(["poly", "5,4"]) == "poly(5,4)" and parse_model(["poly(6,6)"]) == "poly(6,6)"
    with pytest.raises(ValueError, match="--model"):
        parse_model(["poly", "a,b"])


def test_calibrate_saves_a_version(session, study, tmp_path, capsys):
    from core.study import Study

    rc = main([str(session), "--study", str(study), "--report", str(tmp_path / "rep")])
    out = capsys.readouterr()
    assert rc == 0, out.err
    doc = json.loads(out.out)
    assert doc["saved"]["calibration"] == "session.v1" and doc["reprojection_rms_px"] < 0.3
    # the session's lead-disc frames: the veiling glare measured (the generator's is 5 %, 20 mm)
    assert all(0.04 < g["fraction"] < 0.06 and 17 < g["sigma_mm"] < 23 for g in doc["glare"].values())
    assert (tmp_path / "rep" / "report.json").is_file()
    assert (tmp_path / "rep" / "grid_residuals.png").is_file()
    assert "bundle adjustment" in out.err  # the progress bar names the steps
    with Study.open(study) as st:
        assert "session.v1" in st.calibrations and len(st.rig("session.v1")) == 2


def test_bad_input_leaves_the_study_unchanged(session, study, tmp_path, capsys):
    bad = tmp_path / "bad"
    shutil.copytree(session, bad)
    cam = json.loads((bad / "session.json").read_text())["cameras"][1]
    shutil.copy(bad / cam / "flat_70kV" / "0000.tif", bad / cam / "grid" / "0000.tif")
    before = (study / "study.json").read_bytes()
    assert main([str(bad), "--study", str(study), "--quiet"]) == 1
    err = capsys.readouterr().err
    assert f"{cam}/grid/0000.tif (grid frame 0 of camera {cam}): no distortion grid found" in err
    assert (study / "study.json").read_bytes() == before
    assert main([str(tmp_path / "nowhere"), "--study", str(study)]) == 1
    assert "SESSION" in capsys.readouterr().err


def test_ctrl_c_leaves_the_study_unchanged(session, study, monkeypatch, capsys):
    import core.calibration.session as cs

    def cancelled(*a, **k):
        raise cs.CalibrationCancelled("cancelled during beads")

    monkeypatch.setattr(cs, "calibrate_session", cancelled)
    before = (study / "study.json").read_bytes()
    assert main([str(session), "--study", str(study), "--quiet"]) == 130
    assert json.loads(capsys.readouterr().out)["status"] == "cancelled"
    assert (study / "study.json").read_bytes() == before


def test_ctrl_c_during_the_bundle_adjustment_saves_nothing(session, study, monkeypatch, capsys):
    """Ctrl-C while the last step runs (it polls no cancel): the calibration comes back, but the
    command does not save it (calibrate_study polls the cancel once more before saving)."""
    import core.calibration.session as cs

    def interrupted_late(*a, cancel=None, **k):
        cancel.set()  # as the first Ctrl-C does (sigint_cancels)
        return object()  # never saved, never looked at

    monkeypatch.setattr(cs, "calibrate_session", interrupted_late)
    before = (study / "study.json").read_bytes()
    assert main([str(session), "--study", str(study), "--quiet"]) == 130
    captured = capsys.readouterr()
    assert json.loads(captured.out) == {"status": "cancelled", "saved": None}
    assert "cancelled; the study is unchanged" in captured.err
    assert (study / "study.json").read_bytes() == before
    assert not (study / "calibrations").exists() or not any((study / "calibrations").rglob("*.json"))
