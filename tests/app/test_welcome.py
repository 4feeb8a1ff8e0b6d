"""The welcome page of a window started without a study: open the demo, open a study, reopen a
recent one and import a project, all through clicks; the CUDA check runs in a worker and says
what the CPU costs. ``TALUS_SCREENSHOTS=DIR`` keeps a screenshot of the page (welcome.png).

The demo the page writes is the shared test study (``demo_study``, tests/app/conftest.py), copied
by a stand-in for :func:`core.synthetic.demo.make_demo_study` that takes the page's options and
reports progress as it does (writing a demo is the core's test; the foot scene alone took ~3-9 s
here). The start-up check ``talus gui --smoke`` is a test of its own and keeps a process of its
own (~18 s on the loaded 2-core machine, most of the cost): run in this process under pytest-qt,
its window's first paint hung in ``glXSwapBuffers`` (the write to the X server never returned).
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from PySide6 import QtCore, QtWidgets

from app.device_check import CPU_BENCH, GPU_BENCH, DeviceInfo, cpu_slowdown, describe
from tests.app._helpers import copy_study

BENCH = Path(__file__).resolve().parents[2] / "resources" / "benchmarks"
HUNG_MS = 10 * 60_000


def test_quoted_speeds_are_the_measured_ones():
    for quoted in (CPU_BENCH, GPU_BENCH):
        data = json.loads((BENCH / quoted["file"]).read_text(encoding="utf-8"))
        assert data["one_bone"]["end_to_end"]["ms_per_frame"] == quoted["ms_per_frame"]
        assert data["sizes"]["pixels"] == quoted["pixels"]
        assert data["sizes"]["voxel_mm"] == quoted["voxel_mm"]  # the CPU's were twice as coarse
        assert data["device_name"] == quoted["device_name"]
    assert 40 < cpu_slowdown() < 60


def test_describe_says_which_device_and_what_the_cpu_costs():
    level, text = describe(DeviceInfo())
    assert level == "cpu" and "run on the CPU" in text and f"{cpu_slowdown():.0f}× slower" in text
    assert "1.9 s per frame" in text and "38 ms per frame" in text
    assert "192 px (1 mm voxels)" in text and "1024 px (0.5 mm voxels)" in text
    level, text = describe(DeviceInfo(cuda_devices=("NVIDIA H100 80GB HBM3",)))
    assert level == "gpu" and "NVIDIA H100" in text and "CPU" not in text
    level, text = describe(DeviceInfo(error="OSError: warp.so not found"))
    assert level == "error" and "warp.so not found" in text


def _click(qtbot, widget):
    qtbot.mouseClick(widget, QtCore.Qt.MouseButton.LeftButton)


def _window(qtbot):
    from app.main_window import MainWindow
    from app.welcome import show_welcome

    win = MainWindow(create_scene_on_show=False)
    qtbot.addWidget(win)
    page = show_welcome(win)
    win.show()
    return win, page


def _demo_stand_in(monkeypatch, study: Path, written: list):
    """``make_demo_study`` as the page's worker calls it, copying ``study`` instead of rendering."""
    import core.synthetic.demo as demo_module

    def make_demo_study(out_dir, *, progress=None, cancel=None, **options):
        written.append(options)
        assert progress is not None and cancel is not None and not cancel()
        out = Path(out_dir)
        out.parent.mkdir(parents=True, exist_ok=True)
        shutil.copytree(study, out)
        n = json.loads((study / "summary.json").read_text(encoding="utf-8"))["n_frames"]
        for i in range(1, n + 1):  # as the demo reports its frames
            progress(i, n)
        return json.loads((out / "summary.json").read_text(encoding="utf-8"))

    monkeypatch.setattr(demo_module, "make_demo_study", make_demo_study)


@pytest.mark.gui
def test_welcome_page_through_clicks(qtbot, tmp_path, monkeypatch, demo_study):
    from app import settings

    monkeypatch.setenv("TALUS_DEMO_DIR", str(tmp_path / "demo"))
    monkeypatch.setenv("TALUS_SETTINGS_DIR", str(tmp_path / "settings"))
    win, page = _window(qtbot)
    # the window is up before Warp answers; the answer names the device (no GPU here: the CPU)
    assert page.isVisible() and not win.splitter.isVisible()
    assert page.recent.count() == 1 and "No study" in page.recent.item(0).text()
    with qtbot.waitSignal(page.device_checked, timeout=HUNG_MS) as sig:
        pass
    info = sig.args[0]
    level, text = describe(info)
    assert page.device.text() == text and page.device.property("level") == level
    if info.uses_cpu and info.error is None:
        assert "will run on the CPU" in page.device.text() and "× slower" in page.device.text()
    shots = os.environ.get("TALUS_SCREENSHOTS")
    if shots:
        win.resize(1100, 700)
        qtbot.wait(200)
        win.grab().save(str(Path(shots) / "welcome.png"))

    # Open the demo: written once in a worker (with progress), then shown in place of the page
    written, progress = [], []
    _demo_stand_in(monkeypatch, demo_study, written)
    page.pool.progress.connect(lambda key, done, total: progress.append((key, done, total)))
    page.demo_options = dict(n_frames=2, pixels=64, device="cpu", calibration_session=False)
    _click(qtbot, page.demo_button)
    assert not page.demo_button.isEnabled() and "Writing the demo" in page.status.text()
    qtbot.waitUntil(lambda: win.model is not None, timeout=HUNG_MS)
    assert not page.isVisible() and win.splitter.isVisible()
    assert written == [page.demo_options] and progress and progress[-1][0] == "demo"
    assert progress[-1][1] == progress[-1][2] > 0 and page.demo_button.isEnabled()
    demo = tmp_path / "demo"
    assert settings.recent() == [str(demo)]
    win.close()

    # Open a study… (the folder dialog answered), in a new window
    win, page = _window(qtbot)
    monkeypatch.setattr(QtWidgets.QFileDialog, "getExistingDirectory", lambda *a, **k: str(demo))
    _click(qtbot, page.open_button)
    assert win.model is not None and not page.isVisible()
    win.close()

    # a recent study: one click
    win, page = _window(qtbot)
    assert [page.recent.item(i).text() for i in range(page.recent.count())] == [str(demo)]
    item = page.recent.item(0)
    qtbot.mouseClick(page.recent.viewport(), QtCore.Qt.MouseButton.LeftButton,
                     pos=page.recent.visualItemRect(item).center())
    assert win.model is not None and not page.isVisible()
    win.close()

    # Open the demo again: already written, opened at once
    win, page = _window(qtbot)
    _click(qtbot, page.demo_button)
    assert win.model is not None and len(written) == 1
    win.close()


@pytest.mark.gui
def test_gui_smoke_opens_a_study_and_closes(tmp_path, demo_study):
    """An installation's start-up check (the bundle's smoke test runs the same, in a process of its
    own): ``talus gui --smoke --demo DIR`` opens the study and closes the window cleanly."""
    demo = copy_study(demo_study, tmp_path, "demo")
    env = dict(os.environ, TALUS_SETTINGS_DIR=str(tmp_path / "settings"))
    cmd = [sys.executable, "-c", "from app.cli import main; raise SystemExit(main())",
           "gui", "--smoke", "--demo", str(demo)]
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=600, cwd=tmp_path, env=env)
    line = [ln for ln in r.stderr.splitlines() if ln.startswith('{"smoke"')]
    assert r.returncode == 0 and line, r.stderr[-3000:]
    report = json.loads(line[-1])
    assert report["smoke"] == "ok" and report["study_s"] >= report["window_s"] > 0
    assert set(report["bones"]) >= {"talus", "calcaneus"}


@pytest.mark.gui
def test_import_a_project_names_a_bad_file(qtbot, tmp_path, monkeypatch):
    monkeypatch.setenv("TALUS_SETTINGS_DIR", str(tmp_path / "settings"))
    win, page = _window(qtbot)
    cfg = tmp_path / "trial.cfg"
    cfg.write_text("Version 1.2\nmayaCam_csv missing_cam01.txt\n", encoding="utf-8")
    monkeypatch.setattr(QtWidgets.QFileDialog, "getOpenFileName", lambda *a, **k: (str(cfg), ""))
    monkeypatch.setattr(QtWidgets.QFileDialog, "getSaveFileName",
                        lambda *a, **k: (str(tmp_path / "study"), ""))
    shown = []
    monkeypatch.setattr(win, "show_error", lambda title, text: shown.append((title, text)))
    _click(qtbot, page.import_button)
    assert shown and ("trial.cfg" in shown[0][1] or "missing_cam01" in shown[0][1])
    assert win.model is None and page.isVisible()
    assert not (tmp_path / "study" / "study.json").exists()
    # cancelled dialogs: nothing happens
    monkeypatch.setattr(QtWidgets.QFileDialog, "getOpenFileName", lambda *a, **k: ("", ""))
    _click(qtbot, page.import_button)
    assert len(shown) == 1
    win.close()
