"""Tracking > Tracking options…: the window offers what ``talus track`` offers (search, resolution,
similarity, mode, the neighbours' subtraction in sequential tracking, guess, final stage,
confidence, the failure checks' thresholds, the final stage's move check, the trajectory check),
chosen with real clicks and keys."""

from __future__ import annotations

import os

import pytest

pytest.importorskip("PySide6", reason="the GUI extra (PySide6) is not installed")

from PySide6 import QtCore, QtGui, QtWidgets

from app.commands.track import check_choices
from app.tracking_options import FINALS, TrackingOptionsDialog, choices_of, options_from_choices
from tests.app._helpers import copy_study, job_ends, main_window

HUNG_MS = 30 * 60_000  # ceiling for an event that never comes, not a time budget


@pytest.fixture
def window(qtbot):
    """The window without its 3-D scene (the dialog is what is tested)."""
    with main_window(qtbot) as win:
        yield win


def _pick(qtbot, box: QtWidgets.QComboBox, data) -> None:
    """Choose the entry holding ``data`` with the keyboard, as a user would."""
    box.setFocus()
    target = box.findData(data)
    assert target >= 0
    while box.currentIndex() != target:
        key = QtCore.Qt.Key.Key_Down if box.currentIndex() < target else QtCore.Qt.Key.Key_Up
        qtbot.keyClick(box, key)


def _click(qtbot, dialog, button: str) -> None:
    """Click the dialog's standard button ``button`` (``"Ok"``, ``"RestoreDefaults"``...)."""
    qtbot.mouseClick(dialog.buttons.button(getattr(QtWidgets.QDialogButtonBox.StandardButton, button)),
                     QtCore.Qt.MouseButton.LeftButton)


def _accept(qtbot, dialog) -> None:
    """Click *OK* and wait for the dialog to accept."""
    with qtbot.waitSignal(dialog.accepted, timeout=HUNG_MS):
        _click(qtbot, dialog, "Ok")


def test_options_match_the_command_line_defaults():
    opts = options_from_choices()
    assert choices_of(opts) == choices_of(None)
    assert (opts.registration.search, opts.registration.final_scale) == ("newton", 1.0)
    from core.tracking.trial import TrackingOptions

    assert TrackingOptions().registration.search == opts.registration.search  # the tracker's own default
    assert opts.registration.bounds == (5.0, 5.0) and opts.registration.sigma == (1.0, 1.0)
    assert not any(t.options.get("components") for t in opts.registration.terms)
    with pytest.raises(ValueError, match="final_scale"):
        options_from_choices(scale=0.5)


def test_the_metric_choice_round_trips_as_talus_track_metric():
    from app.commands.track import registration_terms

    opts = options_from_choices(metric="components")
    assert opts.registration.terms == registration_terms("components")
    assert any(t.kind == "gc" and t.options["components"] for t in opts.registration.terms)
    c = choices_of(opts)
    assert c["metric"] == "components" and options_from_choices(**c) == opts
    assert choices_of(options_from_choices(**choices_of(None)))["metric"] == "magnitudes"


def test_menu_dialog_sets_the_next_tracking_jobs_options(qtbot, window):
    action = window.tracking.options_action
    assert action is not None and action.text().replace("&", "") == "Tracking options…"
    assert action in window.menuBar().actions()[[a.text() for a in window.menuBar().actions()]
                                                 .index("&Tracking")].menu().actions()
    action.trigger()
    dialog = window.findChild(TrackingOptionsDialog)
    qtbot.waitUntil(dialog.isVisible, timeout=HUNG_MS)
    assert dialog.mode.currentData() == "auto"  # as talus track: joint on flatfield-corrected frames
    assert dialog.similarity.currentData() == "magnitudes"
    assert dialog.search.currentData() == "newton"  # the default, as talus track --search
    _pick(qtbot, dialog.search, "local")  # the quadratic-model search stays selectable
    _pick(qtbot, dialog.resolution, 2.0)
    _pick(qtbot, dialog.mode, "sequential")
    _pick(qtbot, dialog.subtract, "on")  # the neighbours subtracted whatever the frames (the screenshot)
    _pick(qtbot, dialog.similarity, "components")
    assert dialog.final.currentData() == "none"  # the default, as talus track --final
    _pick(qtbot, dialog.final, "likelihood")
    qtbot.mouseClick(dialog.confidence, QtCore.Qt.MouseButton.LeftButton)
    _accept(qtbot, dialog)
    opts = window.tracking.options
    assert choices_of(opts) == {"search": "local", "scale": 2.0, "mode": "sequential", "guess": "velocity",
                                "confidence": False, "metric": "components", "final": "likelihood",
                                "sequential_subtract": "on", "joint_restart": False, "joint_rounds": 1,
                                **check_choices(None)}
    assert any(t.kind == "gc" and t.options.get("components") for t in opts.registration.terms)
    assert opts.refine_likelihood and opts.registration.final == "likelihood"
    assert opts.first_options.final == "likelihood"  # first frames and retries end with it too
    last = window.messages.item(window.messages.count() - 1).text()
    assert "local search, 1/2 resolution, gradient components, sequential" in last and "no confidence" in last
    assert "likelihood final stage, neighbours subtracted" in last
    assert "checks" not in last  # the default checks: not listed

    # re-opened, the dialog shows the current choices; Restore defaults then Cancel changes nothing
    dialog = window.tracking.edit_options()
    qtbot.waitUntil(dialog.isVisible, timeout=HUNG_MS)
    assert dialog.choices() == choices_of(opts)
    shot = dialog.grab()  # painting calls QPaintDevice.metric(): no attribute of the dialog may hide it
    assert not shot.isNull()
    out = os.environ.get("TALUS_SCREENSHOT_DIR")
    if out:
        shot.save(f"{out}/tracking_options.png")
    _click(qtbot, dialog, "RestoreDefaults")
    assert dialog.choices() == choices_of(None)
    with qtbot.waitSignal(dialog.rejected, timeout=HUNG_MS):
        qtbot.keyClick(dialog, QtCore.Qt.Key.Key_Escape)
    assert window.tracking.options is opts

    # the defaults accepted: the summary does not mention the similarity
    dialog = window.tracking.edit_options()
    qtbot.waitUntil(dialog.isVisible, timeout=HUNG_MS)
    _click(qtbot, dialog, "RestoreDefaults")
    _accept(qtbot, dialog)
    assert choices_of(window.tracking.options) == choices_of(None)
    assert window.tracking.options.registration.final is None
    last = window.messages.item(window.messages.count() - 1).text()
    assert "gradient" not in last and "components" not in last and "likelihood" not in last


def test_the_final_stage_choice_is_talus_track_final():
    from app.commands import track

    assert [v for _, v in FINALS] == list(track.FINALS)
    opts = options_from_choices(final="likelihood")
    assert opts.refine_likelihood and opts.registration.final == "likelihood"
    assert choices_of(opts)["final"] == "likelihood" and options_from_choices(**choices_of(opts)) == opts
    assert options_from_choices().registration.final is None  # off by default
    with pytest.raises(ValueError, match="final"):
        options_from_choices(final="ml")


@pytest.mark.gui
def test_tracking_with_the_final_stage_is_refused_on_frames_without_flatfield(qtbot, demo_study, tmp_path):
    """The demo study has no flatfield correction: the window names the trial and tracks nothing."""
    with main_window(qtbot) as win:
        with job_ends(qtbot, win.pool, "overlay"):
            win.open_study(copy_study(demo_study, tmp_path))
        win.tracking.options = options_from_choices(final="likelihood")
        m = win.model
        with pytest.raises(ValueError, match=r"trial 'walk'.*not flatfield-corrected"):
            win.tracking.start(["talus"])
        assert not win.tracking.running and not m.layers[m.index("talus")].locked


def _type(qtbot, box: QtWidgets.QDoubleSpinBox, text: str) -> None:
    """Replace the spin box's number by typing, as a user would (the suffix stays), then Tab."""
    box.setFocus()
    box.selectAll()
    qtbot.keyClicks(box, text)
    qtbot.keyClick(box, QtCore.Qt.Key.Key_Tab)


def test_advanced_checks_set_the_thresholds_with_keys_and_clicks(qtbot, window):
    dialog = window.tracking.edit_options()
    qtbot.waitUntil(dialog.isVisible, timeout=HUNG_MS)
    assert dialog.checks_group.title() == "Advanced checks"
    defaults = check_choices(None)
    assert (dialog.collapse_ratio.value(), dialog.motion_limit.value(), dialog.sigma_limit.value()) == (
        defaults["collapse_ratio"], defaults["motion_limit"], defaults["sigma_limit"])
    assert (dialog.floor_mm.value(), dialog.floor_deg.value()) == defaults["motion_floor"]
    _type(qtbot, dialog.motion_limit, "4")
    _type(qtbot, dialog.sigma_limit, "2.5")
    dialog.collapse_ratio.setFocus()
    for _ in range(2):  # two steps of 0.05 down
        qtbot.keyClick(dialog.collapse_ratio, QtCore.Qt.Key.Key_Down)
    dialog.activateWindow()
    qtbot.waitUntil(dialog.isActiveWindow, timeout=HUNG_MS)
    qtbot.keyClick(dialog.collapse_ratio, QtCore.Qt.Key.Key_O,
                   QtCore.Qt.KeyboardModifier.AltModifier)  # the label's mnemonic: Motion fl&oor
    assert dialog.floor_mm.hasFocus()
    _type(qtbot, dialog.floor_mm, "0.5")
    _type(qtbot, dialog.floor_deg, "1.5")
    _accept(qtbot, dialog)
    opts = window.tracking.options
    assert (opts.collapse_ratio, opts.motion_limit, opts.motion_floor, opts.sigma_limit) == (
        pytest.approx(0.5), 4.0, (0.5, 1.5), 2.5)
    assert options_from_choices(**choices_of(opts)) == opts
    last = window.messages.item(window.messages.count() - 1).text()
    assert "checks: collapse 0.5, motion 4x (floor 0.5 mm, 1.5 deg), sigma 2.5x" in last

    # re-opened it shows them; Restore defaults brings back the tracker's
    dialog = window.tracking.edit_options()
    qtbot.waitUntil(dialog.isVisible, timeout=HUNG_MS)
    assert dialog.choices() == choices_of(opts)
    _click(qtbot, dialog, "RestoreDefaults")
    assert dialog.choices() == choices_of(None)
    with qtbot.waitSignal(dialog.rejected, timeout=HUNG_MS):
        qtbot.keyClick(dialog, QtCore.Qt.Key.Key_Escape)


def test_advanced_checks_hold_their_ranges_and_ok_refuses_an_invalid_value(qtbot, shown_errors):
    dialog = TrackingOptionsDialog()
    qtbot.addWidget(dialog)
    dialog.show()
    qtbot.waitExposed(dialog)
    _type(qtbot, dialog.motion_limit, "0.5")  # below the range: the box keeps a valid value
    assert dialog.motion_limit.value() >= 1
    _type(qtbot, dialog.collapse_ratio, "7")
    assert dialog.collapse_ratio.value() <= 1
    warned = shown_errors  # (title, text) of each refusal, where users get a warning box
    dialog.sigma_limit.setMinimum(0.0)  # a value out of the tracker's range, set from code
    dialog.sigma_limit.setValue(0.5)
    _click(qtbot, dialog, "Ok")
    assert dialog.isVisible() and dialog.result() == 0  # not accepted
    assert len(warned) == 1 and warned[0][1].startswith("sigma_limit: expected a factor >= 1"), warned
    dialog.sigma_limit.setValue(3.0)
    _type(qtbot, dialog.trajectory_limit, "0.9")  # between Off and the range's 1: refused, not Off
    _click(qtbot, dialog, "Ok")
    assert dialog.isVisible() and dialog.result() == 0
    assert len(warned) == 2 and warned[1][1].startswith("trajectory_limit: expected a factor >= 1"), warned


def test_the_final_stage_move_check_is_set_with_the_likelihood_stage_only(qtbot, window):
    dialog = window.tracking.edit_options()
    qtbot.waitUntil(dialog.isVisible, timeout=HUNG_MS)
    boxes = (dialog.stage_move_limit, dialog.stage_move_sigmas, dialog.stage_move_frames,
             dialog.keep_stage_moves)
    defaults = check_choices(None)
    assert (dialog.stage_move_limit.value(), dialog.stage_move_sigmas.value(),
            dialog.stage_move_frames.value()) == (defaults["stage_move_limit"], defaults["stage_move_sigmas"],
                                                  defaults["stage_move_frames"])
    assert not dialog.keep_stage_moves.isChecked() and defaults["stage_move_reject"]
    assert not any(b.isEnabled() for b in boxes)  # no final stage: nothing to check
    assert "--stage-move-limit" in dialog.stage_move_limit.toolTip()
    _pick(qtbot, dialog.final, "likelihood")
    assert all(b.isEnabled() for b in boxes)
    _type(qtbot, dialog.stage_move_limit, "3")
    _type(qtbot, dialog.stage_move_sigmas, "0.25")
    _type(qtbot, dialog.stage_move_frames, "8")
    qtbot.mouseClick(dialog.keep_stage_moves, QtCore.Qt.MouseButton.LeftButton)
    _accept(qtbot, dialog)
    opts = window.tracking.options
    assert opts.refine_likelihood
    assert (opts.stage_move_limit, opts.stage_move_sigmas, opts.stage_move_frames,
            opts.stage_move_reject) == (3.0, 0.25, 8, False)
    assert options_from_choices(**choices_of(opts)) == opts
    last = window.messages.item(window.messages.count() - 1).text()
    assert "stage move check 3x (at least 0.25 sigma, after 8 frames), moves kept" in last
    assert "checks: collapse" not in last  # the failure checks are the defaults

    # re-opened it shows them; back to no final stage they are disabled; Restore defaults resets them
    dialog = window.tracking.edit_options()
    qtbot.waitUntil(dialog.isVisible, timeout=HUNG_MS)
    assert dialog.choices() == choices_of(opts) and dialog.stage_move_frames.isEnabled()
    _pick(qtbot, dialog.final, "none")
    assert not dialog.stage_move_limit.isEnabled() and not dialog.keep_stage_moves.isEnabled()
    _click(qtbot, dialog, "RestoreDefaults")
    assert dialog.choices() == choices_of(None)
    with qtbot.waitSignal(dialog.rejected, timeout=HUNG_MS):
        qtbot.keyClick(dialog, QtCore.Qt.Key.Key_Escape)


def test_the_trajectory_check_is_set_or_turned_off_in_advanced_checks(qtbot, window):
    dialog = window.tracking.edit_options()
    qtbot.waitUntil(dialog.isVisible, timeout=HUNG_MS)
    box = dialog.trajectory_limit
    assert box.value() == check_choices(None)["trajectory_limit"] == 2.5 and box.isEnabled()
    assert "--trajectory-limit" in box.toolTip() and "off the trajectory" in box.toolTip()
    _type(qtbot, box, "3.5")
    _accept(qtbot, dialog)
    opts = window.tracking.options
    assert opts.trajectory_limit == 3.5 and options_from_choices(**choices_of(opts)) == opts
    last = window.messages.item(window.messages.count() - 1).text()
    assert "trajectory check 3.5x" in last and "checks: collapse" not in last

    # its lowest step is "Off": the tracker's None
    dialog = window.tracking.edit_options()
    qtbot.waitUntil(dialog.isVisible, timeout=HUNG_MS)
    box = dialog.trajectory_limit
    assert box.value() == 3.5
    _type(qtbot, box, "1")
    box.setFocus()
    qtbot.keyClick(box, QtCore.Qt.Key.Key_Down)
    assert box.text() == "Off"
    _accept(qtbot, dialog)
    opts = window.tracking.options
    assert opts.trajectory_limit is None and options_from_choices(**choices_of(opts)) == opts
    assert "trajectory check off" in window.messages.item(window.messages.count() - 1).text()

    # re-opened it shows "Off"; Restore defaults brings back the tracker's limit
    dialog = window.tracking.edit_options()
    qtbot.waitUntil(dialog.isVisible, timeout=HUNG_MS)
    assert dialog.trajectory_limit.text() == "Off" and dialog.choices() == choices_of(opts)
    _click(qtbot, dialog, "RestoreDefaults")
    assert dialog.trajectory_limit.value() == 2.5 and dialog.choices() == choices_of(None)
    with qtbot.waitSignal(dialog.rejected, timeout=HUNG_MS):
        qtbot.keyClick(dialog, QtCore.Qt.Key.Key_Escape)


def test_subtract_neighbours_is_chosen_next_to_the_mode(qtbot, window):
    """*Subtract neighbours* (``talus track --sequential-subtract``): the row after *Mode*, automatic
    by default, disabled in the joint mode (which always subtracts), reached by its mnemonic."""
    from app.tracking_options import SUBTRACTS

    assert [v for _, v in SUBTRACTS] == ["auto", "on", "off"]
    dialog = window.tracking.edit_options()
    qtbot.waitUntil(dialog.isVisible, timeout=HUNG_MS)
    form = dialog.layout().itemAt(0).layout()
    assert form.getWidgetPosition(dialog.subtract)[0] == form.getWidgetPosition(dialog.mode)[0] + 1
    assert form.labelForField(dialog.subtract).text() == "Su&btract neighbours:"
    assert dialog.subtract.currentData() == "auto" and dialog.subtract.isEnabled()
    assert "flatfield-corrected" in dialog.subtract.toolTip()
    _pick(qtbot, dialog.mode, "joint")
    assert not dialog.subtract.isEnabled()
    _pick(qtbot, dialog.mode, "sequential")
    assert dialog.subtract.isEnabled()
    dialog.activateWindow()
    qtbot.waitUntil(dialog.isActiveWindow, timeout=HUNG_MS)
    qtbot.keyClick(dialog.mode, QtCore.Qt.Key.Key_B, QtCore.Qt.KeyboardModifier.AltModifier)
    assert dialog.subtract.hasFocus()
    _pick(qtbot, dialog.subtract, "on")
    _accept(qtbot, dialog)
    opts = window.tracking.options
    assert (opts.mode, opts.sequential_subtract) == ("sequential", True)
    assert options_from_choices(**choices_of(opts)) == opts
    assert "neighbours subtracted" in window.messages.item(window.messages.count() - 1).text()

    # re-opened it shows the choice; Off is the tracker's False; Restore defaults brings back auto
    dialog = window.tracking.edit_options()
    qtbot.waitUntil(dialog.isVisible, timeout=HUNG_MS)
    assert dialog.choices() == choices_of(opts) and dialog.subtract.currentData() == "on"
    _pick(qtbot, dialog.subtract, "off")
    _accept(qtbot, dialog)
    assert window.tracking.options.sequential_subtract is False
    assert "neighbours not subtracted" in window.messages.item(window.messages.count() - 1).text()
    dialog = window.tracking.edit_options()
    qtbot.waitUntil(dialog.isVisible, timeout=HUNG_MS)
    _click(qtbot, dialog, "RestoreDefaults")
    assert dialog.subtract.currentData() == "auto" and dialog.choices() == choices_of(None)
    _accept(qtbot, dialog)
    assert window.tracking.options.sequential_subtract is None
    assert "neighbours" not in window.messages.item(window.messages.count() - 1).text()


def test_the_tooltips_are_wrapped_paragraphs_of_the_same_words(qtbot, window):
    """Every tooltip of the dialog is rich text, which Qt word-wraps: shown over the subtraction
    box, the tip is a wrapped label narrower than its words on one line; its words are unchanged."""
    from app.commands.track import CHECKS
    from app.tracking_options import wrapped_tip

    window.tracking.options_action.trigger()
    dialog = window.findChild(TrackingOptionsDialog)
    qtbot.waitUntil(dialog.isVisible, timeout=HUNG_MS)
    tips = [w.toolTip() for w in dialog.findChildren(QtWidgets.QWidget) if w.toolTip()]
    assert len(tips) >= 15 and all(QtGui.Qt.mightBeRichText(t) and t.startswith("<p>") for t in tips)

    def words(tip: str) -> str:
        doc = QtGui.QTextDocument()
        doc.setHtml(tip)
        return doc.toPlainText()

    flag, _default, text = CHECKS["motion_limit"]
    assert words(dialog.motion_limit.toolTip()) == f"{flag}: {text}"  # '>=' and all, as written
    assert "previous round's pose" in words(dialog.joint_restart.toolTip())
    plain = words(dialog.subtract.toolTip())
    assert plain.startswith("Bones tracked one after the other") and plain.endswith("always subtracts them.")
    assert wrapped_tip(dialog.subtract.toolTip()) == dialog.subtract.toolTip()  # wrapped once only

    box = dialog.subtract
    QtWidgets.QToolTip.showText(box.mapToGlobal(box.rect().center()), box.toolTip(), box)
    label = next(w for w in QtWidgets.QApplication.topLevelWidgets()
                 if w.objectName() == "qtooltip_label" and w.isVisible())
    assert label.wordWrap()
    assert label.width() < label.fontMetrics().horizontalAdvance(plain) / 3  # several lines
    assert label.width() < dialog.screen().availableGeometry().width()
    QtWidgets.QToolTip.hideText()
