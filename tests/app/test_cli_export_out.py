"""talus export: a misspelt trial is refused before the output's folder is made (it left an empty
exports/ in the study)."""

from __future__ import annotations

import pytest

from app.cli import main as talus


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    from core.synthetic import make_demo_study

    out = tmp_path_factory.mktemp("demo") / "study"
    make_demo_study(out, n_frames=2, pixels=48, spacing=3.0, tissue_spacing=6.0, device="cpu",
                    calibration_session=False)
    return out


@pytest.mark.parametrize("fmt", ["csv", "xromm-csv"])
def test_a_misspelt_trial_makes_no_folder(study, tmp_path, capsys, fmt):
    assert talus(["export", str(study), "--trial", "wlak", "--format", fmt]) == 1
    assert "no trial named 'wlak'" in capsys.readouterr().err
    assert not (study / "exports").exists()
    assert talus(["export", str(study), "--trial", "wlak", "--format", fmt,
                  "--out", str(tmp_path / "new" / "x.csv")]) == 1
    assert not (tmp_path / "new").exists()
    assert talus(["export", str(study), "--trial", "walk", "--format", fmt,
                  "--out", str(tmp_path / "new" / "x.csv")]) == 0  # a good one makes it
    assert (tmp_path / "new" / "x.csv").is_file()
