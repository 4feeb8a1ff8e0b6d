"""talus report: a one-page HTML/PDF trial report of a tracked study; errors name the argument."""

from __future__ import annotations

import json

import numpy as np
import pytest

from app.cli import EXIT_ERROR, main
from core.study import Study
from core.synthetic import make_demo_study


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    out = tmp_path_factory.mktemp("report") / "study"
    make_demo_study(out, n_frames=3, pixels=48, seed=1, device="cpu", spacing=2.0, tissue_spacing=8.0,
                    calibration_session=False)
    truth = np.load(out / "poses" / "talus.npy")
    with Study.open(out, mode="w") as st:  # tracking results, one flagged, without running the tracker
        tr = st.trial("walk")
        for f in range(3):
            why = ["score 0.40 below 0.85 x the recent median"] if f == 1 else []
            conf = {"translation_mm": 0.1, "rotation_deg": 0.2}
            tr.record_pose("talus", f, truth[f], score=0.8,
                           tracking={"flags": why, "converged": not why, "confidence": conf})
    return out


def test_report_html_and_pdf(study, tmp_path, capsys):
    assert main(["report", str(study), "--trial", "walk", "--out", str(tmp_path / "r.html")]) == 0
    assert json.loads(capsys.readouterr().out)["report"] == str(tmp_path / "r.html")
    html = (tmp_path / "r.html").read_text(encoding="utf-8")
    assert "Calibration" in html and "data:image/png;base64," in html
    assert "frame 1 talus: score 0.40 below 0.85 x the recent median" in html  # the flagged frame
    assert "<td>talus</td><td>3</td><td>1</td>" in html  # tracked 3, flagged 1
    assert main(["report", str(study), "--trial", "walk", "--out", str(tmp_path / "r.pdf")]) == 0
    assert (tmp_path / "r.pdf").read_bytes()[:4] == b"%PDF"


def test_report_errors_name_the_argument(study, tmp_path, capsys):
    assert main(["report", str(tmp_path / "none"), "--trial", "walk"]) == EXIT_ERROR
    assert "STUDY" in capsys.readouterr().err
    assert main(["report", str(study), "--trial", "walk", "--out", str(tmp_path / "r.txt")]) == EXIT_ERROR
    assert "--out" in capsys.readouterr().err
    assert main(["report", str(study), "--trial", "nope"]) == EXIT_ERROR
    assert "--trial" in capsys.readouterr().err
    assert not list(tmp_path.glob("r.*"))
