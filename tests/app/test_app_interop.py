"""Interop in the command and the window: ``talus import`` of an XMALab project, File → Import
project… (Autoscoper .cfg or XMALab .xma → a new study, opened) and File → Export… (every pose
format of core.study.exports; the files read back equal)."""

from __future__ import annotations

import csv
import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest
from PySide6 import QtCore, QtWidgets

from app.main_window import MainWindow
from core.study import Study
from tests.core.study.test_import_xma import frames, make


def test_cli_imports_an_xma_project(tmp_path, capsys):
    from app.cli import main

    p = make(tmp_path)
    assert main(["import", str(p), "--study", str(tmp_path / "st")]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["trials"] == {"hop_1": 4} and summary["format"] == "xmalab-xma"
    assert summary["markers"] == {"hop_1": 2} and summary["calibrations"] == ["xmalab.v1"]
    assert main(["import", str(p), "--out", str(tmp_path / "st")]) == 1  # a study is there already
    assert "already holds a study" in capsys.readouterr().err
    assert main(["import", str(p), "--out", str(tmp_path / "s2"), "--tra", "x.tra"]) == 1
    assert "--tra: only for an Autoscoper .cfg" in capsys.readouterr().err
    assert not (tmp_path / "s2").exists()
    assert np.isfinite(summary["trials"]["hop_1"])


# ---------------------------------------------------------------------------- the window
N = 3  # frames of the shared demo study (tests/app/conftest.py)


@pytest.fixture(scope="module")
def demo_folder(tmp_path_factory, demo_study):
    """The shared 96-px demo study with poses at every frame: frame 0's keyframe moved a little per
    frame."""
    from scipy.spatial.transform import Rotation

    out = Path(shutil.copytree(demo_study, tmp_path_factory.mktemp("interop") / "study"))
    with Study.open(out, mode="w") as st:
        tr = st.trial("walk")
        for k, b in enumerate(tr.bones):
            T0 = tr.poses(b)[0]
            for f in range(1, N):
                D = np.eye(4)
                D[:3, :3] = Rotation.from_rotvec([0.01 * f, -0.004 * k, 0.002 * f]).as_matrix()
                D[:3, 3] = [0.3 * f, -0.2 * f, 0.1 * k]
                tr.record_pose(b, f, T0 @ D, score=0.9)
    return out


def _window(qtbot, tmp_path, monkeypatch):
    monkeypatch.setenv("TALUS_SETTINGS_DIR", str(tmp_path / "settings"))
    win = MainWindow(device="cpu", create_scene_on_show=False)
    qtbot.addWidget(win)
    win.show()
    return win


@pytest.fixture
def window(qtbot, tmp_path, monkeypatch):
    win = _window(qtbot, tmp_path, monkeypatch)
    yield win
    win.close()


def _menu_action(win, text):
    file_menu = next(a.menu() for a in win.menuBar().actions() if a.text() == "&File")
    return next(a for a in file_menu.actions() if a.text().replace("&", "").startswith(text))


@pytest.mark.gui
def test_import_project_menu_opens_an_xma_project(window, qtbot, tmp_path, monkeypatch):
    win = window
    p = make(tmp_path)
    _menu_action(win, "Import project").trigger()
    dlg = win.last_dialog
    assert dlg.isVisible() and not dlg.import_button.isEnabled()
    monkeypatch.setattr(QtWidgets.QFileDialog, "getOpenFileName", lambda *a, **k: (str(p), ""))
    qtbot.mouseClick(dlg.project_browse, QtCore.Qt.MouseButton.LeftButton)
    assert dlg.project.text() == str(p) and dlg.study.text() == str(tmp_path / "lab_study")
    assert dlg.search.isEnabled() and not dlg.tra.isEnabled()  # the .xma's option, not the .cfg's
    closed = []
    dlg.finished.connect(closed.append)
    dlg.import_button.click()
    qtbot.waitUntil(lambda: win.session is not None, timeout=120_000)
    assert closed == [QtWidgets.QDialog.DialogCode.Accepted]
    assert win.session.study.folder == tmp_path / "lab_study" and win.session.trial_name == "hop_1"
    assert win.session.study.read_report("markers", "hop_1")["markers"][0]["description"] == "bead 1"


@pytest.mark.gui
def test_import_project_dialog_says_why_it_failed(window, qtbot, tmp_path):
    win = window
    v = [frames(tmp_path / "c", c) for c in (1, 2)]
    p = make(tmp_path / "c", views=[v[0][:3], v[1][:3]])  # lists 3 of the 4 frames in each folder
    dlg = win.import_project_dialog()
    dlg.project.setText(str(p))
    dlg.import_button.click()
    qtbot.waitUntil(lambda: "Not imported" in dlg.status.text(), timeout=120_000)
    assert "holds 4 TIFF frames but the trial lists 3" in dlg.status.text()
    assert dlg.isVisible() and dlg.import_button.isEnabled() and win.session is None
    assert not (tmp_path / "c" / "lab_study").exists()
    dlg.project.setText(str(tmp_path / "x.txt"))
    assert not dlg.import_button.isEnabled()
    dlg.reject()


@pytest.mark.gui
def test_import_project_menu_opens_the_wrist_cfg(window, qtbot, tmp_path, sample_data):
    """The wrist sample's version 1.2 .cfg and a .tra of radius and ulna at frame 0099 (in
    Autoscoper's volume frame) through the dialog: the window opens the study with the poses as
    keyframes and renders both bones at frame 1 (``TALUS_SCREENSHOTS=DIR`` keeps the picture;
    ``resources/screenshots/wrist_cfg_imported.png``)."""
    from core.io.autoscoper import write_tra
    from core.io.autoscoper_pose import tra_from_lab_from_bone
    from core.samples import load_wrist_sample
    from core.studies.io.autoscoper_wrist import BONES, wrist_tra_poses
    from tests.core.study.test_study_import_project import wrist_cfg

    data = sample_data / "autoscoper_wrist"
    if not data.is_dir():
        pytest.skip(reason=f"wrist sample not found at {data}")
    cfg = wrist_cfg(tmp_path, data)
    sample, talus = load_wrist_sample(data), wrist_tra_poses()
    tra = np.full((3, 2, 4, 4), np.nan)
    for b, bone in enumerate(BONES):
        tra[1, b] = tra_from_lab_from_bone(talus[b], sample.volumes[bone])
    write_tra(tmp_path / "wrist.tra", tra)
    win = window
    win.resize(1600, 900)
    dlg = win.import_project_dialog()
    dlg.project.setText(str(cfg))
    assert dlg.tra.isEnabled() and not dlg.search.isEnabled()
    dlg.tra.setText(str(tmp_path / "wrist.tra"))
    dlg.import_button.click()
    qtbot.waitUntil(lambda: win.session is not None, timeout=300_000)
    st = win.session.study
    assert st.folder == tmp_path / "wrist_study"
    assert set(st.bones) == {"rad_dcm_cropped", "uln_dcm_cropped"}
    for k, b in enumerate(("rad_dcm_cropped", "uln_dcm_cropped")):
        np.testing.assert_allclose(st.trial("trial").poses(b)[1], talus[k], atol=1e-6)
    rendered = []
    win.pool.finished.connect(lambda key, r: key == "overlay" and rendered.append(key))
    win.model.set_frame(1)
    qtbot.waitUntil(lambda: bool(rendered), timeout=300_000)
    folder = os.environ.get("TALUS_SCREENSHOTS")
    if folder:
        Path(folder).mkdir(parents=True, exist_ok=True)
        assert win.grab().save(str(Path(folder) / "wrist_cfg_imported.png"))


def _read_back(fmt, path, names, poses, study):
    """The poses of a written export, (n_frames, n_bones, 4, 4), or None for formats that hold
    something else (checked inline)."""
    if fmt == "tra-talus":
        from core.io.autoscoper_tra import read_tra

        return read_tra(path, n_volumes=len(names))
    if fmt == "tra-autoscoper":
        from core.io.autoscoper_pose import lab_from_bone_from_tra
        from core.io.autoscoper_tra import read_tra

        T = read_tra(path, n_volumes=len(names))
        return np.stack([[lab_from_bone_from_tra(T[f, k], study.bone_volume(b)) for k, b in enumerate(names)]
                         for f in range(len(T))])
    if fmt == "csv":
        with open(path, newline="") as fh:
            rows = list(csv.reader(fh))[1:]
        return np.array([[[float(v) for v in r[1 + 16 * k:17 + 16 * k]] for k in range(len(names))]
                         for r in rows]).reshape(-1, len(names), 4, 4)
    if fmt == "json":
        import json as _json

        doc = _json.loads(path.read_text())
        return np.stack([np.array(doc["bones"][b]["poses"]).reshape(-1, 4, 4) for b in names], axis=1)
    if fmt == "xromm-csv":
        from core.io.rigid_body_csv import read_rigid_body_csv

        r = read_rigid_body_csv(path)
        assert list(r.bodies) == names and list(r.frames) == list(range(1, N + 1))
        return r.poses
    if fmt == "c3d":
        from core.io.c3d import read_c3d

        r = read_c3d(path)
        assert list(r.bones) == names and r.rate == 50.0  # the dialog's frame rate
        return r.poses
    if fmt == "mot":
        from core.io.opensim import kinematics_to_poses, read_mot

        return kinematics_to_poses(read_mot(path), names)
    if fmt == "tfm":
        from core.io.slicer_tfm import read_slicer_tfm

        got = np.stack([read_slicer_tfm(path / f"{b}.tfm") for b in names])
        np.testing.assert_allclose(got, np.stack([poses[b][0] for b in names]), atol=1e-6)
        return None
    if fmt == "jts":
        from core.io.jointtrack import jts_to_lab, read_jts

        cam = study.trial("walk").rig()[0]
        return np.stack([jts_to_lab(read_jts(path / f"{b}.jts"), cam) for b in names], axis=1)
    if fmt == "trc":
        from core.io.opensim import read_trc

        r = read_trc(path)
        assert len(r.names) == 4 * len(names)
        for k, b in enumerate(names):
            np.testing.assert_allclose(r.xyz[:, 4 * k], poses[b][:, :3, 3], atol=1e-6)
        return None
    if fmt == "jcs":
        from core.io.jcs_csv import read_jcs_csv

        r = read_jcs_csv(path)
        assert len(r.frames) == N and np.isfinite(r.values).all()
        return None
    if fmt == "csv-6dof":
        with open(path, newline="") as fh:
            rows = list(csv.reader(fh))
        assert len(rows) == N + 1 and len(rows[1]) == 1 + 6 * len(names)
        return None
    raise AssertionError(f"no reader for {fmt}")


@pytest.mark.gui
def test_export_menu_writes_every_format_that_reads_back(qtbot, demo_folder, tmp_path, monkeypatch):
    from core.study.exports import available_formats

    pytest.importorskip("ezc3d")
    folder = shutil.copytree(demo_folder, tmp_path / "study")
    win = _window(qtbot, tmp_path, monkeypatch)
    try:
        win.open_study(folder)
        _menu_action(win, "Export").trigger()
        dlg = win.last_dialog
        rows = [dlg.formats.item(i).text() for i in range(dlg.formats.count())]
        # the two .tra say which frame they hold
        assert any("Talus-frame .tra" in r and "not for Autoscoper" in r for r in rows)
        assert any("Autoscoper .tra (Autoscoper's volume frame)" in r for r in rows)
        assert sum(r.startswith("Plots:") for r in rows) == 3
        assert sum(r.startswith("Trial report") for r in rows) == 2
        study = win.session.study
        trial = study.trial("walk")
        names = list(trial.bones)
        poses = {b: trial.poses(b) for b in names}
        want = np.stack([poses[b] for b in names], axis=1)
        formats = available_formats()
        assert "tra" not in formats and {"tra-talus", "tra-autoscoper"} <= set(formats)
        for k, (kind, fmt, suffix, folder_fmt, _) in enumerate(dlg._choices):
            if kind != "poses":
                continue
            dlg.formats.setCurrentRow(k)
            assert dlg.bones.isEnabled() and fmt in dlg.about.text()
            assert dlg.rate.isEnabled() == (fmt in ("c3d", "mot", "trc", "jcs"))
            dlg.rate.setValue(50.0)
            out = tmp_path / "out" / (fmt if folder_fmt else f"{fmt}{suffix}")
            out.parent.mkdir(exist_ok=True)
            dlg.path.setText(str(out))
            qtbot.mouseClick(dlg.export_button, QtCore.Qt.MouseButton.LeftButton)
            assert dlg.status.text().startswith("Exported"), (fmt, dlg.status.text())
            got = _read_back(fmt, out, names, poses, study)
            if got is not None:
                np.testing.assert_allclose(got, want, atol=1e-6, err_msg=fmt)
        # one bone only, the path from Browse… (a patched file dialog)
        dlg.select("csv")
        for i in range(1, dlg.bones.count()):
            dlg.bones.item(i).setCheckState(QtCore.Qt.CheckState.Unchecked)
        target = tmp_path / "out" / "one.csv"
        monkeypatch.setattr(QtWidgets.QFileDialog, "getSaveFileName", lambda *a, **k: (str(target)[:-4], ""))
        dlg.browse.click()
        assert dlg.path.text() == str(target)
        dlg.export_button.click()
        np.testing.assert_allclose(_read_back("csv", target, names[:1], poses, study), want[:, :1], atol=0)
        # the plots and the report, as the Plots dock writes them
        dlg.select("plots", ".pdf")
        assert not dlg.bones.isEnabled()
        dlg.path.setText(str(tmp_path / "out" / "plots.pdf"))
        dlg.export_button.click()
        assert (tmp_path / "out" / "plots.pdf").read_bytes()[:4] == b"%PDF"
        dlg.select("report", ".html")
        dlg.export_button.click()  # the default path: <study>/exports/walk_report.html
        assert "Calibration" in (folder / "exports" / "walk_report.html").read_text()
        # a wrong suffix is said in the dialog, in red, nothing written
        dlg.select("report", ".pdf")
        dlg.path.setText(str(tmp_path / "out" / "report.txt"))
        dlg.export_button.click()
        assert "Not exported: Save to: expected a .pdf file" in dlg.status.text()
        assert not (tmp_path / "out" / "report.txt").exists()
        dlg.reject()
    finally:
        win.close()


def test_cli_export_names_both_tra_frames(demo_folder, tmp_path, capsys):
    from app.cli import main
    from core.io.autoscoper_tra import read_tra

    folder = shutil.copytree(demo_folder, tmp_path / "study")
    for fmt in ("tra", "tra-autoscoper", "tra-talus", "csv-6dof", "json"):
        assert main(["export", str(folder), "--trial", "walk", "--format", fmt,
                     "--out", str(tmp_path / f"{fmt}.out")]) == 0, capsys.readouterr().err
    assert (tmp_path / "tra.out").read_bytes() == (tmp_path / "tra-autoscoper.out").read_bytes()
    with Study.open(folder) as st:
        tr = st.trial("walk")
        want = np.stack([tr.poses(b) for b in tr.bones], axis=1)
    np.testing.assert_allclose(read_tra(tmp_path / "tra-talus.out", n_volumes=want.shape[1]), want, atol=0)
    assert main(["export", str(folder), "--trial", "walk", "--format", "csv"]) == 0
    assert (folder / "exports" / "walk_csv.csv").is_file()  # the dialog's name (test_cli_walk.py)
