"""Tracking > Tracking options…: *Joint rounds* (``talus track --joint-rounds``,
``TrackingOptions.joint_rounds``, 1 by default) and *Restart joint rounds from the prediction*
(``--joint-restart``, ``TrackingOptions.joint_restart``) — a spin box and a check box under the mode,
disabled with the sequential mode, their tooltips the options' help; the restart ticked at one round
raises the rounds to 2 (as --joint-restart alone), the rounds set to 1 untick it; chosen with the mouse
and keys, the next tracking job gets them."""

from __future__ import annotations

import os

import pytest
from PySide6 import QtCore

from app.tracking_options import TrackingOptionsDialog, choices_of, options_from_choices
from tests.app._helpers import copy_study, job_ends, main_window
from tests.app.test_app_tracking_options import HUNG_MS, _accept, _click, _pick

pytestmark = pytest.mark.gui


def test_the_restart_is_ticked_and_reaches_the_tracking_job(qtbot, demo_study, tmp_path, monkeypatch):
    import core.tracking.from_study as from_study

    got = []

    def fake_track_study(study, trial, bones, frames, *, options=None, **kw):
        got.append((list(bones), options))
        return None, {"summary": {"status": "complete", "results": 0}, "stopped": {}, "flagged": []}

    with main_window(qtbot) as win:
        with job_ends(qtbot, win.pool, "overlay"):
            win.open_study(copy_study(demo_study, tmp_path))
        win.tracking.options_action.trigger()
        dialog = win.findChild(TrackingOptionsDialog)
        qtbot.waitUntil(dialog.isVisible, timeout=HUNG_MS)
        box, rounds = dialog.joint_restart, dialog.joint_rounds
        form = dialog.layout().itemAt(0).layout()
        row = form.getWidgetPosition(box)[0]
        assert form.getWidgetPosition(rounds)[0] == form.getWidgetPosition(dialog.subtract)[0] + 1
        assert row == form.getWidgetPosition(rounds)[0] + 1  # under the mode, the rounds then the restart
        assert not box.isChecked() and box.isEnabled()  # off by default; auto may track jointly
        assert rounds.value() == 1 and rounds.isEnabled()  # one round by default
        tip = box.toolTip()
        assert "previous round's pose" in tip and "182 evaluations" in tip and "seed 3" in tip
        assert "raises Joint rounds to 2" in tip
        assert "121.8 against 202.3" in rounds.toolTip() and "first frame" in rounds.toolTip()
        _pick(qtbot, dialog.mode, "sequential")  # one round: nothing to restart
        assert not box.isEnabled() and not rounds.isEnabled()
        _pick(qtbot, dialog.mode, "joint")
        assert box.isEnabled() and rounds.isEnabled()
        qtbot.mouseClick(box, QtCore.Qt.MouseButton.LeftButton)
        assert box.isChecked() and rounds.value() == 2  # ticked at one round: two rounds
        rounds.setFocus()
        qtbot.keyClick(rounds, QtCore.Qt.Key.Key_Down)  # one round: the restart unticked
        assert rounds.value() == 1 and not box.isChecked()
        qtbot.keyClick(rounds, QtCore.Qt.Key.Key_Up)
        qtbot.keyClick(rounds, QtCore.Qt.Key.Key_Up)
        assert rounds.value() == 3 and not box.isChecked()  # more rounds leave the restart as it was
        qtbot.mouseClick(box, QtCore.Qt.MouseButton.LeftButton)
        assert box.isChecked() and rounds.value() == 3  # ticked at three rounds: kept
        shot = dialog.grab()
        out = os.environ.get("TALUS_SCREENSHOT_DIR")
        if out:
            shot.save(f"{out}/tracking_options_joint_restart.png")
        _accept(qtbot, dialog)
        opts = win.tracking.options
        assert (opts.mode, opts.joint_restart, opts.joint_rounds) == ("joint", True, 3)
        assert options_from_choices(**choices_of(opts)) == opts
        last = win.messages.item(win.messages.count() - 1).text()
        assert "3 joint rounds, joint rounds from the prediction" in last

        monkeypatch.setattr(from_study, "track_study", fake_track_study)
        with job_ends(qtbot, win.pool, "tracking"):
            win.tracking.start(["talus", "calcaneus"])
        assert len(got) == 1 and got[0][0] == ["talus", "calcaneus"]
        assert got[0][1].joint_restart is True and got[0][1].mode == "joint" and got[0][1].joint_rounds == 3

        # re-opened it shows the tick; Restore defaults clears it
        dialog = win.tracking.edit_options()
        qtbot.waitUntil(dialog.isVisible, timeout=HUNG_MS)
        assert dialog.joint_restart.isChecked() and dialog.choices() == choices_of(opts)
        _click(qtbot, dialog, "RestoreDefaults")
        assert not dialog.joint_restart.isChecked() and dialog.choices() == choices_of(None)
        assert dialog.joint_rounds.value() == 1
        _accept(qtbot, dialog)
        assert win.tracking.options.joint_restart is False and win.tracking.options.joint_rounds == 1
        assert "joint rounds" not in win.messages.item(win.messages.count() - 1).text()
