"""Tracking > Tracking options…: *Restart joint rounds from the prediction* (``talus track
--joint-restart``, ``TrackingOptions.joint_restart``) — a check box under the mode, off by default,
disabled with the sequential mode, its tooltip the option's help; ticked with the mouse, the next
tracking job gets the option."""

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
        box = dialog.joint_restart
        form = dialog.layout().itemAt(0).layout()
        row = form.getWidgetPosition(box)[0]
        assert row == form.getWidgetPosition(dialog.subtract)[0] + 1  # under the mode
        assert not box.isChecked() and box.isEnabled()  # off by default; auto may track jointly
        tip = box.toolTip()
        assert "previous round's pose" in tip and "182 evaluations" in tip and "seed 4" in tip
        _pick(qtbot, dialog.mode, "sequential")  # one round: nothing to restart
        assert not box.isEnabled()
        _pick(qtbot, dialog.mode, "joint")
        assert box.isEnabled()
        qtbot.mouseClick(box, QtCore.Qt.MouseButton.LeftButton)
        assert box.isChecked()
        shot = dialog.grab()
        out = os.environ.get("TALUS_SCREENSHOT_DIR")
        if out:
            shot.save(f"{out}/tracking_options_joint_restart.png")
        _accept(qtbot, dialog)
        opts = win.tracking.options
        assert (opts.mode, opts.joint_restart) == ("joint", True)
        assert options_from_choices(**choices_of(opts)) == opts
        assert "joint rounds from the prediction" in win.messages.item(win.messages.count() - 1).text()

        monkeypatch.setattr(from_study, "track_study", fake_track_study)
        with job_ends(qtbot, win.pool, "tracking"):
            win.tracking.start(["talus", "calcaneus"])
        assert len(got) == 1 and got[0][0] == ["talus", "calcaneus"]
        assert got[0][1].joint_restart is True and got[0][1].mode == "joint"

        # re-opened it shows the tick; Restore defaults clears it
        dialog = win.tracking.edit_options()
        qtbot.waitUntil(dialog.isVisible, timeout=HUNG_MS)
        assert dialog.joint_restart.isChecked() and dialog.choices() == choices_of(opts)
        _click(qtbot, dialog, "RestoreDefaults")
        assert not dialog.joint_restart.isChecked() and dialog.choices() == choices_of(None)
        _accept(qtbot, dialog)
        assert win.tracking.options.joint_restart is False
        assert "joint rounds" not in win.messages.item(win.messages.count() - 1).text()
