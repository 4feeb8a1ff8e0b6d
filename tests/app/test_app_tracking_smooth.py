"""Tracking > Tracking options…, *Smooth the poses afterwards* (``talus track --smooth`` in the
window; off by default, remembered with the options): the window's tracking job, once its run is
complete, smooths the tracked bones' poses over the trial into
``results/reports/smoothing/<trial>.json``; a cancelled run is not smoothed. The tracker is a
stand-in recording noisy true poses with a confidence σ (nothing registered).
``TALUS_SCREENSHOTS=DIR`` keeps ``tracking_options_smooth.png``."""

from __future__ import annotations

import json
import os
import time
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("PySide6", reason="the GUI extra (PySide6) is not installed")

from PySide6 import QtCore

from core.geometry.transforms import pose_from_params
from tests.app._helpers import HUNG_JOB_MS, copy_study, job_ends, main_window
from tests.app.test_app_tracking_options import HUNG_MS, _accept, _click

N = 10
SIGMA = [0.05, 0.05, 0.05, 0.2, 0.2, 0.2]
REPORT = Path("results") / "reports" / "smoothing" / "walk.json"


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    from core.synthetic import make_demo_study

    out = tmp_path_factory.mktemp("smooth_window") / "study"
    make_demo_study(out, n_frames=N, pixels=32, seed=2, device="cpu", spacing=3.0, tissue_spacing=8.0,
                    calibration_session=False)
    return out


@pytest.fixture
def window(qtbot):
    with main_window(qtbot) as win:
        yield win


def _fake_track(truths, *, wait_for_cancel=False):
    """A track_study stand-in: each bone's true poses moved by noise, with a confidence σ, recorded
    and reported as tracking reports them; with ``wait_for_cancel`` it then waits for the job's cancel
    and still returns a complete result (a smoother that looked only at the result would run)."""
    from core.tracking.bones import bone_model
    from core.tracking.results import FrameResult, TrackingResult

    def fake(study, trial, bones=None, frames=None, *, progress=None, cancel=None, **_):
        g = np.random.default_rng(0)
        tr = study.trial(trial)
        names = list(bones or tr.bones)
        for b in names:
            c = bone_model(study.bone_volume(b), name=b, threshold=200.0, mesh=False).centroid
            for f in range(N):
                e = g.normal(size=6) * 0.5 * np.r_[SIGMA[:3], np.radians(SIGMA[3:])]
                pose = pose_from_params(e, center=c, base=truths[b][f])
                tr.record_pose(b, f, pose, score=0.8,
                               tracking={"flags": [], "converged": True, "confidence": {"sigma": SIGMA}})
                if progress is not None:  # the window's live results and progress bar (Cancel shown)
                    progress(f + 1, N, FrameResult(b, f, pose, 0.8, 1, 0.0, True,
                                                   confidence={"sigma": SIGMA}))
        deadline = time.monotonic() + HUNG_JOB_MS / 1000
        while wait_for_cancel and not cancel():
            assert time.monotonic() < deadline, "the job was never cancelled"
            time.sleep(0.02)
        res = TrackingResult(tuple(names), tuple(range(N)), {}, "complete", 0.0)
        return res, {"summary": {"status": "complete", "results": N * len(names)}, "flagged": []}

    return fake


def _last(window) -> str:
    return window.messages.item(window.messages.count() - 1).text()


def _messages(window) -> list[str]:
    return [window.messages.item(i).text() for i in range(window.messages.count())]


def test_smooth_afterwards_is_off_by_default_and_remembered(qtbot, window):
    assert window.tracking.smooth is False
    dialog = window.tracking.edit_options()
    qtbot.waitUntil(dialog.isVisible, timeout=HUNG_MS)
    box = dialog.smooth_after
    assert not box.isChecked() and not dialog.smooth() and box.isEnabled()
    assert "results/reports/smoothing/TRIAL.json" in box.toolTip() and "Off by default" in box.toolTip()
    form = dialog.layout().itemAt(0).layout()
    assert form.getWidgetPosition(box)[0] == form.getWidgetPosition(dialog.confidence)[0] + 1
    qtbot.mouseClick(box, QtCore.Qt.MouseButton.LeftButton)
    assert box.isChecked() and dialog.smooth()
    folder = os.environ.get("TALUS_SCREENSHOTS")
    if folder:  # resources/screenshots/tracking_options_smooth.png
        assert dialog.grab().save(str(Path(folder) / "tracking_options_smooth.png"))
    _accept(qtbot, dialog)
    assert window.tracking.smooth is True and "poses smoothed afterwards" in _last(window)
    assert window.tracking.options is not None  # the tracker's options, which do not hold it

    dialog = window.tracking.edit_options()  # re-opened: ticked; Restore defaults unticks it
    qtbot.waitUntil(dialog.isVisible, timeout=HUNG_MS)
    assert dialog.smooth_after.isChecked()
    _click(qtbot, dialog, "RestoreDefaults")
    assert not dialog.smooth_after.isChecked()
    with qtbot.waitSignal(dialog.rejected, timeout=HUNG_MS):  # cancelled: still on
        qtbot.keyClick(dialog, QtCore.Qt.Key.Key_Escape)
    assert window.tracking.smooth is True


def _tick_smooth(qtbot, window, on: bool) -> None:
    dialog = window.tracking.edit_options()
    qtbot.waitUntil(dialog.isVisible, timeout=HUNG_MS)
    if dialog.smooth_after.isChecked() != on:
        qtbot.mouseClick(dialog.smooth_after, QtCore.Qt.MouseButton.LeftButton)
    _accept(qtbot, dialog)
    assert window.tracking.smooth is on


def test_the_tracking_job_smooths_a_complete_run(qtbot, window, demo, tmp_path, monkeypatch):
    from core.study import Study
    from core.tracking import from_study
    from core.tracking.smoothing_trial import smooth_trial

    study = copy_study(demo, tmp_path)
    truths = {p.stem: np.load(p) for p in (study / "poses").glob("*.npy")}
    monkeypatch.setattr(from_study, "track_study", _fake_track(truths))
    window.open_study(study)
    bones = [layer.name for layer in window.model.layers]

    with job_ends(qtbot, window.pool, "tracking"):  # off by default: no report
        window.tracking.track_all()
    assert not (study / REPORT).exists()
    assert not any("Smoothed poses" in m for m in _messages(window))

    _tick_smooth(qtbot, window, True)
    notes = []
    window.pool.progress.connect(lambda key, d, t: notes.append(window.tracking.last_feedback))
    with job_ends(qtbot, window.pool, "tracking"):
        window.tracking.track_all()
    assert any(n.startswith("Smoothing the poses of ") for n in notes), notes  # the status bar said so
    rep = json.loads((study / REPORT).read_text())
    assert sorted(rep["bones"]) == sorted(bones) and not rep["skipped"]
    assert f"Smoothed poses of {', '.join(sorted(bones))} written to {REPORT.as_posix()}" in _last(window)
    with Study.open(study) as st:  # the same as talus track --smooth's; the journal keeps the tracked poses
        want = smooth_trial(st, "walk", bones, write=False)
        for b in bones:
            np.testing.assert_allclose(rep["bones"][b]["poses"], want["bones"][b]["poses"], atol=1e-9)
            assert not np.allclose(np.array(rep["bones"][b]["poses"], float), st.trial("walk").poses(b))
    assert not window.tracking.running


def test_a_cancelled_run_is_not_smoothed(qtbot, window, demo, tmp_path, monkeypatch):
    from core.tracking import from_study

    study = copy_study(demo, tmp_path)
    truths = {p.stem: np.load(p) for p in (study / "poses").glob("*.npy")}
    monkeypatch.setattr(from_study, "track_study", _fake_track(truths, wait_for_cancel=True))
    window.open_study(study)
    _tick_smooth(qtbot, window, True)
    with job_ends(qtbot, window.pool, "tracking", expect="cancelled"):
        window.tracking.track_all()
        qtbot.waitUntil(lambda: window.cancel_button.isVisible(), timeout=HUNG_MS)
        qtbot.mouseClick(window.cancel_button, QtCore.Qt.MouseButton.LeftButton)
    assert not (study / REPORT).exists()
    assert "Tracking cancelled" in _last(window)
    assert not any("Smooth" in m for m in _messages(window) if not m.startswith("Tracking options"))


def test_smooth_after_writes_nothing_when_cancelled_while_smoothing(demo, tmp_path):
    from app.tracking_actions import smooth_after
    from core.study import Study
    from core.tracking.smoothing_trial import smoothed_poses

    study = copy_study(demo, tmp_path)
    truths = {p.stem: np.load(p) for p in (study / "poses").glob("*.npy")}
    with Study.open(study, mode="w") as st:
        _fake_track(truths)(st, "walk")
        bones = list(st.trial("walk").bones)[:1]
        assert smooth_after(st, "walk", bones, cancel=lambda: True) is None
        assert not (study / REPORT).exists()
        out = smooth_after(st, "walk", bones, cancel=lambda: False)
        assert out == {"report": REPORT.as_posix(), "bones": bones, "skipped": {}}
        rep = json.loads((study / REPORT).read_text())
        np.testing.assert_allclose(np.array(rep["bones"][bones[0]]["poses"], float),
                                   smoothed_poses(st, "walk", bones)[bones[0]], atol=1e-5)  # 6 digits


def test_the_windows_batch_smooths_each_complete_trial(qtbot, window, demo, tmp_path, monkeypatch):
    """*Track in batch…* with the box ticked: ``talus batch --smooth`` on the window's study (the
    batch's tasks a stand-in reporting complete on poses recorded before)."""
    pytest.importorskip("distributed")
    import core.tracking.batch as core_batch
    from core.study import Study

    study = copy_study(demo, tmp_path)
    truths = {p.stem: np.load(p) for p in (study / "poses").glob("*.npy")}
    with Study.open(study, mode="w") as st:
        _fake_track(truths)(st, "walk")

    def run_batch(tasks, settings=None, *, on_event=None, **kw):
        recs = [dict(key=t.key, study=t.study, trial=t.trial, bones=list(t.bones), status="complete",
                     seconds=0.0) for t in tasks]
        return core_batch.summarize(tasks, recs, [], wall_s=0.1, workers=1)

    monkeypatch.setattr(core_batch, "run_batch", run_batch)
    window.open_study(study)
    _tick_smooth(qtbot, window, True)
    window.model.select("talus")
    window.tracking.batch_action.trigger()
    dlg = window.tracking.batch.dialog
    qtbot.waitExposed(dlg)
    with qtbot.waitSignal(window.tracking.batch.finished, timeout=HUNG_MS) as done:
        qtbot.mouseClick(dlg.start_button, QtCore.Qt.MouseButton.LeftButton)
    s = done.args[0]
    assert s["status"] == "complete" and s["smoothed"][0]["bones"] == ["talus"], s.get("smoothed")
    rep = json.loads((study / REPORT).read_text())
    assert sorted(rep["bones"]) == ["talus"]
    assert any(m.startswith("Batch: ") and f"smoothed poses of talus in {REPORT.as_posix()}" in m
               for m in _messages(window))
