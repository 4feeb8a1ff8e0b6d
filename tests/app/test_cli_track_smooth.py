"""talus track --smooth: the tracked bones' smoothed poses written beside the results
(core.tracking.smoothing_trial), the journal's poses left as they were; off by default."""

from __future__ import annotations

import json

import numpy as np
import pytest

from core.geometry.transforms import pose_from_params
from core.study import Study

N = 12
SIGMA = [0.05, 0.05, 0.05, 0.2, 0.2, 0.2]


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    from core.synthetic import make_demo_study

    out = tmp_path_factory.mktemp("smooth") / "study"
    make_demo_study(out, n_frames=N, pixels=32, seed=2, device="cpu", spacing=3.0, tissue_spacing=8.0,
                    calibration_session=False)
    return out


def _centroids(study):
    from core.tracking.bones import bone_model

    with Study.open(study) as st:
        return {b: bone_model(st.bone_volume(b), name=b, threshold=200.0, mesh=False).centroid
                for b in st.trial("walk").bones}


def _fake_track(truths, centres):
    """A track_study stand-in: records each bone's true poses moved by noise, with a confidence σ
    (frame 5 flagged), and returns a complete result."""
    from core.tracking.results import TrackingResult

    def fake(study, trial, bones=None, frames=None, **_):
        g = np.random.default_rng(0)
        tr = study.trial(trial)
        names = list(bones or tr.bones)
        for b in names:
            for f in range(N):
                e = g.normal(size=6) * 0.5 * np.r_[SIGMA[:3], np.radians(SIGMA[3:])]
                pose = pose_from_params(e, center=centres[b], base=truths[b][f])
                flags = ["off the trajectory"] if f == 5 else []
                tr.record_pose(b, f, pose, score=0.8, tracking={"flags": flags, "converged": True,
                                                               "confidence": {"sigma": SIGMA}})
        res = TrackingResult(tuple(names), tuple(range(N)), {}, "complete", 0.0)
        return res, {"summary": {"status": "complete"}, "options": {}}

    return fake


def test_track_smooth_writes_the_smoothed_poses_beside_the_results(study, monkeypatch, capsys):
    from app.cli import main as talus
    from core.tracking import from_study

    truths = {p.stem: np.load(p) for p in (study / "poses").glob("*.npy")}
    centres = _centroids(study)
    monkeypatch.setattr(from_study, "track_study", _fake_track(truths, centres))
    report = study / "results" / "reports" / "smoothing" / "walk.json"
    assert talus(["track", str(study), "--trial", "walk", "--device", "cpu", "--quiet"]) == 0
    assert "smoothed" not in json.loads(capsys.readouterr().out) and not report.exists()  # off by default
    assert talus(["track", str(study), "--trial", "walk", "--device", "cpu", "--quiet", "--smooth"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["smoothed"]["report"] == "results/reports/smoothing/walk.json"
    rep = json.loads(report.read_text())
    with Study.open(study) as st:
        trial = st.trial("walk")
        assert sorted(rep["bones"]) == sorted(out["smoothed"]["bones"]) == sorted(trial.bones)
        for b, r in rep["bones"].items():
            raw = trial.poses(b)  # the journal keeps the tracked poses
            assert r["frames"] == [0, N - 1] and len(r["poses"]) == N and len(r["covariance"]) == N
            sm = np.array(r["poses"], dtype=float)
            assert sm.shape == (N, 4, 4) and not np.allclose(sm, raw)
            assert np.all(np.array(r["sigma"]) > 0)
            c = centres[b]
            assert np.allclose(r["center"], c, atol=1e-4)

            def err(P, c=c, b=b):  # the centroid's error, mm
                return np.linalg.norm(P[:, :3, :3] @ c + P[:, :3, 3] - truths[b][:, :3, :3] @ c
                                      - truths[b][:, :3, 3], axis=1)

            # 12 frames over most of a stance move the bones up to 17 mm a frame: too few for the model to
            # gain much (MAX_SCALE keeps it from smoothing the motion away); the smoothed poses stay near
            assert np.sqrt(np.mean(err(sm) ** 2)) < 0.1 and np.sqrt(np.mean(err(raw) ** 2)) < 0.1


def test_bone_series_reads_sigma_flags_and_hand_poses():
    from core.study.results import PoseRecord
    from core.tracking.smoothing_trial import bone_series

    conf = {"sigma": [0.1] * 5 + [None]}
    recs = {0: PoseRecord(0, np.eye(4), 0.5, tracking={"flags": ["x"], "confidence": conf}),
            2: PoseRecord(2, np.eye(4), 0.5)}  # a hand-set pose: no σ
    P, S, fl = bone_series(recs, [0, 1, 2])
    assert np.isnan(P[1]).all() and np.isfinite(P[[0, 2]]).all()
    assert fl.tolist() == [True, False, False]
    assert np.isinf(S[0, 5]) and np.isnan(S[2]).all() and S[0, 0] == 0.1


@pytest.mark.gui
def test_export_dialog_writes_the_smoothed_poses(study, qtbot, tmp_path, monkeypatch):
    """File → Export…, *Smoothed poses* ticked: the CSV holds the smoothed poses
    (core.tracking.smoothing_trial.smoothed_poses), unticked the tracked ones; off by default, and
    off (disabled) for the plots and the report."""
    import csv

    from PySide6 import QtCore

    from app.main_window import MainWindow
    from core.tracking import from_study
    from core.tracking.smoothing_trial import smoothed_poses

    truths = {p.stem: np.load(p) for p in (study / "poses").glob("*.npy")}
    with Study.open(study, mode="w") as st:  # the stand-in's tracked poses (the CLI test's, if it ran)
        _fake_track(truths, _centroids(study))(st, "walk")
    monkeypatch.setattr(from_study, "track_study", None)  # nothing tracks here
    monkeypatch.setenv("TALUS_SETTINGS_DIR", str(tmp_path / "settings"))
    win = MainWindow(device="cpu", create_scene_on_show=False)
    qtbot.addWidget(win)
    win.show()
    try:
        win.open_study(study)
        dlg = win.review.export_dialog()
        dlg.select("csv")
        assert dlg.smoothed.isEnabled() and not dlg.smoothed.isChecked()
        names = dlg.chosen_bones()

        def export(name, smoothed):
            if dlg.smoothed.isChecked() != smoothed:
                qtbot.mouseClick(dlg.smoothed, QtCore.Qt.MouseButton.LeftButton)
            assert dlg.smoothed.isChecked() == smoothed
            dlg.path.setText(str(tmp_path / name))
            qtbot.mouseClick(dlg.export_button, QtCore.Qt.MouseButton.LeftButton)
            assert dlg.status.text().startswith("Exported"), dlg.status.text()
            with open(tmp_path / name, newline="") as fh:
                rows = list(csv.reader(fh))[1:]
            return np.array([[[float(v) for v in r[1 + 16 * k:17 + 16 * k]] for k in range(len(names))]
                             for r in rows]).reshape(-1, len(names), 4, 4)

        raw = export("raw.csv", False)
        sm = export("smoothed.csv", True)
        dlg.grab().save(str(tmp_path / "export_smoothed.png"))
        with Study.open(study) as st:
            want = smoothed_poses(st, "walk", names)
            tracked = np.stack([st.trial("walk").poses(b) for b in names], axis=1)
        np.testing.assert_allclose(raw, tracked, atol=1e-9)
        np.testing.assert_allclose(sm, np.stack([want[b] for b in names], axis=1), atol=1e-9)
        assert not np.allclose(sm, raw)
        dlg.select("report", ".html")
        assert not dlg.smoothed.isEnabled()
        dlg.reject()
    finally:
        win.close()


def test_a_second_run_of_other_bones_adds_to_the_report(study, monkeypatch, capsys):
    """Smoothing the talus, then the tibia, leaves both in the trial's report (the second run does not
    replace the first's bones); smoothing the talus again replaces its own entry only."""
    from app.cli import main as talus
    from core.tracking import from_study

    truths = {p.stem: np.load(p) for p in (study / "poses").glob("*.npy")}
    monkeypatch.setattr(from_study, "track_study", _fake_track(truths, _centroids(study)))
    report = study / "results" / "reports" / "smoothing" / "walk.json"
    report.unlink(missing_ok=True)
    base = ["track", str(study), "--trial", "walk", "--device", "cpu", "--quiet", "--smooth"]
    assert talus([*base, "--bones", "talus"]) == 0
    assert sorted(json.loads(report.read_text())["bones"]) == ["talus"]
    assert talus([*base, "--bones", "tibia"]) == 0
    capsys.readouterr()
    rep = json.loads(report.read_text())
    assert sorted(rep["bones"]) == ["talus", "tibia"]
    talus_before = rep["bones"]["talus"]["poses"]
    assert talus([*base, "--bones", "talus"]) == 0
    rep = json.loads(report.read_text())
    assert sorted(rep["bones"]) == ["talus", "tibia"]
    assert np.allclose(np.array(rep["bones"]["talus"]["poses"], float), np.array(talus_before, float))
