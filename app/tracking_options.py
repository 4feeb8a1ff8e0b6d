"""Tracking > Options…: the choices ``talus track`` offers on its command line, in the window.

The dialog edits the window's :class:`core.tracking.trial.TrackingOptions` (``TrackingActions.options``)
through :func:`options_from_choices` — defined in :mod:`app.commands.track` and used by ``talus
track`` itself for ``--search``, ``--scale``, ``--metric``, ``--mode``, ``--guess``, ``--final`` and
``--no-confidence``, so the two cannot drift:

* **Search** — *Gauss–Newton* (the default: the faster engine, pose derivatives from one launch
  per iteration) or *local* (fitted quadratic models, the default before; ``talus track --search``);
* **Resolution** — full, ½ or ¼: the pyramid scale of a tracked frame's last level (detector
  pixels per DRR pixel). Reduced resolution is several times faster, chiefly without a GPU;
* **Similarity** — the gradient correlation of the gradient magnitudes (the default) or of the
  gradient components (Penney's form: better on overlapping bones in the harder synthetic trial,
  slower);
* **Mode** — automatic (the default, as ``talus track``: jointly when the trial's frames are
  flatfield-corrected, else one after the other), bones one after the other, or jointly (each
  with the others' DRRs subtracted);
* **Subtract neighbours** (next to the mode; ``talus track --sequential-subtract``,
  ``TrackingOptions.sequential_subtract``) — whether a bone tracked one after the other is searched
  with the other bones' DRRs subtracted: automatic (the default: on where the trial's frames are
  flatfield-corrected, off on frames divided by the full scale, whose intensities the DRRs do not
  match), on or off. Disabled with the joint mode, which always subtracts them;
* **Joint rounds** (under the mode; ``talus track --joint-rounds``, ``TrackingOptions.joint_rounds``,
  1 by default, 1–5 here) — joint tracking's rounds per frame; its tooltip says why one and what a
  second is for (:data:`app.commands.track.ROUNDS_HELP`);
* **Restart joint rounds from the prediction** (under the rounds; ``talus track --joint-restart``,
  ``TrackingOptions.joint_restart``, off by default) — joint tracking's rounds after the first start
  each bone from its prediction, not its previous round's pose; its tooltip gives the measured gain
  and cost (:data:`app.commands.track.RESTART_FIGURES`). One round has nothing to restart: ticking it
  at one round raises *Joint rounds* to 2 (as ``--joint-restart`` alone implies two rounds), and
  setting the rounds to 1 unticks it. Both are disabled with the sequential mode, which has one
  round;
* **Guess** — the next frame's start: velocity, previous pose or a spline through the track;
* **Final stage** — none (the default) or *likelihood*: every registration ends with a weighted
  least-squares refinement of the pose against the line-integral image
  (``TrackingOptions.refine_likelihood``; robust pixel weights). On the synthetic 1024² walking
  trial (one NVIDIA H200) it brought the talus closer to its Cramér–Rao bound (alone 2.21/2.15× →
  1.48/1.47×, mm/°) and improved every bone's rotation, but worsened the calcaneus's translation
  in joint mode (1.45 → 1.90×), at 3.7 → 31.0 ms per frame for the talus alone and 18.3 → 142 ms
  for three bones jointly. It needs flatfield-corrected frames: a trial without a flatfield
  correction is refused when the job starts (:func:`app.commands.track.final_stage_problem`);
* **Confidence** — the pose uncertainty of every frame (costs a few renders per frame);
* **Smooth the poses afterwards** (under it; ``talus track --smooth``, off by default) — once a run is
  complete, each tracked bone's poses are also smoothed over the trial
  (:func:`core.tracking.smoothing_trial.smooth_trial`) into ``results/reports/smoothing/<trial>.json``;
  the journal's poses stay the results. Not a tracker option: the window's tracking job does it
  (:mod:`app.tracking_actions`), so the dialog holds it beside the options (:meth:`TrackingOptionsDialog.
  smooth`), not in them;
* **Advanced checks** — the thresholds of the checks that flag frames for review
  (``talus track --collapse-ratio``, ``--motion-limit``, ``--motion-floor``, ``--sigma-limit``;
  :data:`app.commands.track.CHECKS`): a score below the *collapse* ratio × the bone's recent median
  score, a pose farther from the motion prediction than the *motion limit* × the bone's recent
  median miss (never below the *motion floor*, mm and degrees) and a confidence σ over the *σ
  limit* × the bone's recent median σ are flagged. With the likelihood final stage only (the
  boxes are enabled when it is chosen): its *move check* (``--stage-move-limit``,
  ``--stage-move-sigmas``, ``--stage-move-frames``, ``--keep-stage-moves``) flags a frame whose
  stage moved the pose more than the *stage move limit* × the median move of the bone's last good
  frames and more than the given fraction of its own translation σ, once the bone has that many
  good frames; such a frame keeps the similarity's pose unless *Keep flagged stage moves* is
  ticked — or the move is confirmed first (the stage run again from the far side of its pose lands
  on the same pose: the stage's pose kept, unflagged, with a note;
  :data:`core.tracking.frame_step.STAGE_MOVE_CONFIRM`). *Trajectory limit* (``--trajectory-limit``,
  :mod:`core.tracking.flags_post`): once a run is complete, a frame whose pose stands off the local
  fit through its neighbours' poses by more than this × the bone's median residual is flagged *off
  the trajectory*, and it scales the rule for frames next to flagged ones too (*off the trajectory
  next to flagged frames*, 0.7 × it without them in the fit); its lowest step, *Off*, turns both off
  (``TrackingOptions.trajectory_limit=None``); its tooltip is the option's help. *Backward limit*
  (``--backward-limit``, :mod:`core.tracking.backward_check`): once a run is complete, its first frame
  is registered again from the frames after it and flagged *first frame off its backward registration*
  where the two registrations disagree by more than this × the bone's median trajectory residual
  (default 1.25); its lowest step, *Off*, skips that registration (``TrackingOptions.backward_limit=None``).
  The spin boxes
  hold each to its valid range; an invalid value set from code is refused on *OK* with the option
  and its range named.

Every tooltip of the dialog is one paragraph of rich text (:func:`wrapped_tip`), which Qt wraps
to a readable width; the words are those of the plain text.
"""

from __future__ import annotations

import html

from PySide6 import QtGui, QtWidgets

from .commands.track import CHECKS, SMOOTH_HELP, check_choices, choices_of, options_from_choices
from .commands.track_options import RESTART_FIGURES, ROUNDS_HELP

__all__ = ["CHECK_RANGES", "FINALS", "MAX_ROUNDS", "METRICS", "OFF_FIELDS", "RESOLUTIONS", "SEARCHES",
           "SMOOTH_TIP", "SUBTRACTS", "TrackingOptionsDialog", "choices_of", "options_from_choices",
           "wrapped_tip"]

#: (label, search) pairs shown in the dialog.
SEARCHES = (("Gauss–Newton (faster)", "newton"), ("Local (quadratic models)", "local"))
#: (label, final pyramid scale) pairs shown in the dialog.
RESOLUTIONS = (("Full", 1.0), ("½ (4× fewer pixels)", 2.0), ("¼ (16× fewer pixels)", 4.0))
#: (label, ``talus track --metric``) pairs shown in the dialog.
METRICS = (("Gradient magnitudes", "magnitudes"), ("Gradient components", "components"))
_MODES = (("Automatic (joint on flatfield-corrected frames)", "auto"),
          ("Sequential (one bone after another)", "sequential"), ("Joint (bones together)", "joint"))
#: (label, ``talus track --sequential-subtract``) pairs shown in the dialog.
SUBTRACTS = (("Automatic (on flatfield-corrected frames)", "auto"), ("On", "on"), ("Off", "off"))
_GUESSES = (("Velocity", "velocity"), ("Previous pose", "previous"), ("Spline", "spline"))
#: The *Joint rounds* box's maximum (the dialog's own; ``TrackingOptions`` takes any integer >= 1).
MAX_ROUNDS = 5
#: (label, ``talus track --final``) pairs shown in the dialog.
FINALS = (("None", "none"), ("Likelihood refinement (flatfield-corrected frames)", "likelihood"))
#: The *Advanced checks* spin boxes: name -> (minimum, maximum, step, decimals, suffix); the ranges
#: are ``TrackingOptions``' (the upper bounds of the factors and the floor are the dialog's own).
CHECK_RANGES = {
    "collapse_ratio": (0.0, 1.0, 0.05, 2, " × recent median score"),
    "motion_limit": (1.0, 100.0, 0.5, 1, " × recent median miss"),
    "floor_mm": (0.0, 50.0, 0.25, 2, " mm"),
    "floor_deg": (0.0, 90.0, 0.25, 2, " °"),
    "sigma_limit": (1.0, 100.0, 0.5, 1, " × recent median σ"),
    "stage_move_limit": (1.0, 100.0, 0.5, 1, " × recent median move"),
    "stage_move_sigmas": (0.0, 10.0, 0.1, 2, " × the frame's σ"),
    "stage_move_frames": (1, 1000, 1, 0, " good frames"),  # an integer: a QSpinBox
    # its minimum, a step below the tracker's 1, reads "Off" (any value below 1: None)
    "trajectory_limit": (1.0 - 0.25, 100.0, 0.25, 2, " × median residual"),
    # as the trajectory limit: its minimum, a step below the tracker's 1, reads "Off"
    "backward_limit": (1.0 - 0.25, 100.0, 0.25, 2, " × median residual"),
}
#: The *Advanced checks* spin boxes whose minimum means the check is off (the choice None).
OFF_FIELDS = ("trajectory_limit", "backward_limit")

#: The *Advanced checks* rows, in order: (:data:`CHECKS` field, label); ``motion_floor`` is two spin
#: boxes (``floor_mm``, ``floor_deg``), every other field one spin box named as the field.
_CHECK_ROWS = (("collapse_ratio", "Score &collapse below:"), ("motion_limit", "Motion &limit:"),
               ("motion_floor", "Motion fl&oor:"), ("sigma_limit", "&Uncertain above:"),
               ("trajectory_limit", "&Trajectory limit:"), ("backward_limit", "Back&ward limit:"),
               ("stage_move_limit", "Stage mo&ve limit:"),
               ("stage_move_sigmas", "Stage move &at least:"), ("stage_move_frames", "Move check &needs:"))
_SPIN_FIELDS = tuple(name for name, _label in _CHECK_ROWS if name != "motion_floor")


def wrapped_tip(text: str) -> str:
    """``text`` as a rich-text paragraph (Qt word-wraps rich-text tooltips; a plain one is a single
    line as wide as the screen); text that already is rich text is kept."""
    if not text or QtGui.Qt.mightBeRichText(text):
        return text
    return f"<p>{html.escape(text, quote=False)}</p>"


def _words(text: str) -> str:
    """A help text of ``talus track`` in the dialog's typography."""
    return (text.replace("1024^2", "1024²").replace("x the Cramer-Rao", "× the Cramér–Rao").replace("->", "→")
            .replace("mm/deg", "mm/°").replace(" deg)", "°)").replace("60 percent", "60 %"))


#: *Smooth the poses afterwards*' tooltip: ``talus track --smooth``'s help in the dialog's typography
SMOOTH_TIP = _words("O" + SMOOTH_HELP[1:].replace("this 2-core CPU", "a 2-core CPU").replace(
    "Rauch-Tung-Striebel", "Rauch–Tung–Striebel").replace("Cramer-Rao", "Cramér–Rao").replace(
    " x the single", " × the single").replace(" deg against", "° against").replace(
    "Default off", "Off by default") + ".")


def _spin(name: str, value: float | None, tip: str) -> QtWidgets.QDoubleSpinBox | QtWidgets.QSpinBox:
    lo, hi, step, decimals, suffix = CHECK_RANGES[name]
    if value is None:  # an OFF_FIELDS check turned off: the box's minimum
        value = lo
    if decimals == 0:
        box = QtWidgets.QSpinBox()
        box.setRange(int(lo), int(hi))
        box.setValue(int(value))
    else:
        box = QtWidgets.QDoubleSpinBox()
        box.setRange(lo, hi)
        box.setDecimals(decimals)
        box.setValue(float(value))
    box.setSingleStep(step)
    box.setSuffix(suffix)
    box.setToolTip(tip)
    if name in OFF_FIELDS:
        box.setSpecialValueText("Off")
    return box


def _spin_value(name: str, box):
    """The choice a spin box holds: its value, or None for an :data:`OFF_FIELDS` box at its minimum
    (*Off*); a typed value between *Off* and the limits' 1 is refused on *OK*, naming the
    option."""
    v = box.value()
    return None if name in OFF_FIELDS and v <= box.minimum() else v


def _combo(pairs, value) -> QtWidgets.QComboBox:
    box = QtWidgets.QComboBox()
    for label, v in pairs:
        box.addItem(label, v)
    values = [v for _, v in pairs]
    box.setCurrentIndex(values.index(value) if value in values else 0)
    return box


class TrackingOptionsDialog(QtWidgets.QDialog):
    """Choose search, resolution, similarity, mode, the neighbours' subtraction, the joint rounds and their
    restart, guess, final stage,
    confidence and the failure checks' thresholds; :meth:`options` gives the result."""

    def __init__(self, options=None, parent=None, *, smooth: bool = False) -> None:
        super().__init__(parent)
        self.setWindowTitle("Tracking options")
        c = choices_of(options)
        self.search = _combo(SEARCHES, c["search"])
        self.resolution = _combo(RESOLUTIONS, c["scale"])
        self.similarity = _combo(METRICS, c["metric"])  # not "metric": that would hide QPaintDevice.metric()
        self.mode = _combo(_MODES, c["mode"])
        self.subtract = _combo(SUBTRACTS, c["sequential_subtract"])
        self.guess = _combo(_GUESSES, c["guess"])
        self.final = _combo(FINALS, c["final"])
        self.joint_rounds = QtWidgets.QSpinBox()
        self.joint_rounds.setRange(1, max(MAX_ROUNDS, c["joint_rounds"]))
        self.joint_rounds.valueChanged.connect(
            lambda n: self.joint_rounds.setSuffix(" round a frame" if n == 1 else " rounds a frame"))
        self.joint_rounds.setValue(c["joint_rounds"])
        self.joint_rounds.setSuffix(" round a frame" if c["joint_rounds"] == 1 else " rounds a frame")
        self.joint_rounds.setToolTip(_words(ROUNDS_HELP.replace(" (default 1; 2 with --joint-restart)", "")
                                            .replace("joint tracking: rounds", "Joint tracking's rounds")
                                            .replace("an integer >= 1", "1 by default")) + ".")
        self.joint_restart = QtWidgets.QCheckBox("Restart joint rounds from the &prediction")
        self.joint_restart.setChecked(c["joint_restart"])
        self.joint_restart.setToolTip(
            "Joint tracking: start each bone's rounds after the first from its prediction, not from its "
            "previous round's pose. One round has none: ticked at one joint round it raises Joint rounds "
            "to 2 (as talus track --joint-restart alone does), and Joint rounds set to 1 unticks it. "
            + _words(RESTART_FIGURES) + ".")
        self.joint_restart.toggled.connect(self._restart_needs_rounds)
        self.joint_rounds.valueChanged.connect(self._rounds_without_restart)
        self.confidence = QtWidgets.QCheckBox("Pose uncertainty of every frame")
        self.confidence.setChecked(c["confidence"])
        self.smooth_after = QtWidgets.QCheckBox("Smoot&h the poses afterwards")
        self.smooth_after.setObjectName("tracking-smooth")
        self.smooth_after.setChecked(bool(smooth))
        self.smooth_after.setToolTip(SMOOTH_TIP)
        self.search.setToolTip("Gauss–Newton (the default) needs fewer renders per frame; local fits "
                               "quadratic models and was the more accurate on a CPU at coarse views; "
                               "first frames and retries always search globally")
        self.resolution.setToolTip("Reduced resolution tracks several times faster (chiefly on a CPU), "
                                   "with a larger error")
        self.similarity.setToolTip("Gradient components (Penney's form): better on overlapping bones in the "
                               "harder synthetic trial, slower")
        self.subtract.setToolTip(
            "Bones tracked one after the other: search each with the other bones' DRRs subtracted (those "
            "registered earlier in the frame at their poses, the others at their guesses). Automatic: on "
            "where the frames are flatfield-corrected, off where they are divided by the full scale. On the "
            "synthetic 1024² trial (one NVIDIA H100) frames over 4× their Cramér–Rao bound left unflagged "
            "(tibia/talus/calcaneus) 9/7/0 → 0/0/0 on seed 0, 9/0/0 → 8/0/0 and 4/1/0 → 2/0/0 on seeds 1 and "
            "2, as joint tracking. The joint mode always subtracts them.")
        self.final.setToolTip(
            "Likelihood: every registration ends with a robustly weighted least-squares refinement against "
            "the line-integral image. On the synthetic 1024² trial (one NVIDIA H200): talus alone 2.21/2.15× "
            "→ 1.48/1.47× its Cramér–Rao bound (mm/°), 3.7 → 31.0 ms per frame; jointly better rotation for "
            "every bone, calcaneus translation worse (1.45 → 1.90×), 18.3 → 142 ms per frame. Needs "
            "flatfield-corrected frames.")
        form = QtWidgets.QFormLayout()
        form.addRow("&Search:", self.search)
        form.addRow("&Resolution:", self.resolution)
        form.addRow("S&imilarity:", self.similarity)
        form.addRow("&Mode:", self.mode)
        form.addRow("Su&btract neighbours:", self.subtract)
        form.addRow("&Joint rounds:", self.joint_rounds)
        form.addRow("", self.joint_restart)
        form.addRow("&Guess:", self.guess)
        form.addRow("&Final stage:", self.final)
        form.addRow("", self.confidence)
        form.addRow("", self.smooth_after)
        checks = self._checks_group(c)
        buttons = QtWidgets.QDialogButtonBox(
            QtWidgets.QDialogButtonBox.StandardButton.Ok | QtWidgets.QDialogButtonBox.StandardButton.Cancel
            | QtWidgets.QDialogButtonBox.StandardButton.RestoreDefaults)
        buttons.accepted.connect(self.accept)
        buttons.rejected.connect(self.reject)
        buttons.button(QtWidgets.QDialogButtonBox.StandardButton.RestoreDefaults).clicked.connect(
            self.restore_defaults)
        self.buttons = buttons
        self.mode.currentIndexChanged.connect(self._enable_subtract)
        self._enable_subtract()
        layout = QtWidgets.QVBoxLayout(self)
        layout.addLayout(form)
        layout.addWidget(checks)
        layout.addWidget(buttons)
        for w in (self, *self.findChildren(QtWidgets.QWidget)):  # the long tooltips wrapped
            w.setToolTip(wrapped_tip(w.toolTip()))

    def _checks_group(self, c: dict) -> QtWidgets.QGroupBox:
        """The *Advanced checks* group: the failure checks' thresholds (``talus track``'s options)."""
        tip = {k: f"{flag}: {text}" for k, (flag, _default, text) in CHECKS.items()}
        self.floor_mm = _spin("floor_mm", c["motion_floor"][0], tip["motion_floor"])
        self.floor_deg = _spin("floor_deg", c["motion_floor"][1], tip["motion_floor"])
        floor = QtWidgets.QHBoxLayout()
        floor.setContentsMargins(0, 0, 0, 0)
        floor.addWidget(self.floor_mm)
        floor.addWidget(self.floor_deg)
        group = QtWidgets.QGroupBox("Advanced checks")
        group.setToolTip("Thresholds of the checks that flag frames for review: a lower limit or floor, or a "
                         "higher collapse ratio, flags more frames")
        form = QtWidgets.QFormLayout(group)
        for name, label in _CHECK_ROWS:
            if name == "motion_floor":
                form.addRow(label, floor)
                form.labelForField(floor).setBuddy(self.floor_mm)
            else:  # a spin box named as the option
                setattr(self, name, _spin(name, c[name], tip[name]))
                form.addRow(label, getattr(self, name))
        self.keep_stage_moves = QtWidgets.QCheckBox("&Keep flagged stage moves")
        self.keep_stage_moves.setChecked(not c["stage_move_reject"])
        self.keep_stage_moves.setToolTip(tip["stage_move_reject"])
        form.addRow("", self.keep_stage_moves)
        self.final.currentIndexChanged.connect(self._enable_stage_moves)
        self._enable_stage_moves()
        self.checks_group = group
        return group

    def _stage_move_widgets(self) -> tuple:
        return (self.stage_move_limit, self.stage_move_sigmas, self.stage_move_frames, self.keep_stage_moves)

    def _enable_stage_moves(self, *_args) -> None:
        """The final stage's move check is enabled with the likelihood final stage only."""
        on = self.final.currentData() == "likelihood"
        for w in self._stage_move_widgets():
            w.setEnabled(on)

    def _enable_subtract(self, *_args) -> None:
        """The neighbours' subtraction is a choice of sequential tracking: disabled in the joint mode;
        the joint rounds' restart one of joint tracking: disabled in the sequential mode."""
        self.subtract.setEnabled(self.mode.currentData() != "joint")
        self.joint_rounds.setEnabled(self.mode.currentData() != "sequential")
        self.joint_restart.setEnabled(self.mode.currentData() != "sequential")

    def _restart_needs_rounds(self, on: bool) -> None:
        """Ticked at one round (which has nothing to restart): two rounds, as ``--joint-restart``."""
        if on and self.joint_rounds.value() < 2:
            self.joint_rounds.setValue(2)

    def _rounds_without_restart(self, n: int) -> None:
        """One round has nothing to restart: the restart unticked."""
        if n < 2 and self.joint_restart.isChecked():
            self.joint_restart.setChecked(False)

    def restore_defaults(self) -> None:
        for box in (self.search, self.resolution, self.similarity, self.mode, self.subtract, self.guess,
                    self.final):
            box.setCurrentIndex(0)
        self.confidence.setChecked(True)
        self.smooth_after.setChecked(False)
        self.joint_restart.setChecked(False)
        self.joint_rounds.setValue(1)
        self._set_checks(check_choices(None))

    def _set_checks(self, c: dict) -> None:
        for name in _SPIN_FIELDS:
            box = getattr(self, name)
            box.setValue(box.minimum() if c[name] is None else c[name])
        self.floor_mm.setValue(c["motion_floor"][0])
        self.floor_deg.setValue(c["motion_floor"][1])
        self.keep_stage_moves.setChecked(not c["stage_move_reject"])

    def choices(self) -> dict:
        return {"search": self.search.currentData(), "scale": float(self.resolution.currentData()),
                "mode": self.mode.currentData(), "guess": self.guess.currentData(),
                "confidence": self.confidence.isChecked(), "metric": self.similarity.currentData(),
                "final": self.final.currentData(), "sequential_subtract": self.subtract.currentData(),
                "joint_restart": self.joint_restart.isChecked(), "joint_rounds": self.joint_rounds.value(),
                **{k: _spin_value(k, getattr(self, k)) for k in _SPIN_FIELDS},
                "motion_floor": (self.floor_mm.value(), self.floor_deg.value()),
                "stage_move_reject": not self.keep_stage_moves.isChecked()}

    def options(self):
        return options_from_choices(**self.choices())

    def smooth(self) -> bool:
        """*Smooth the poses afterwards*: whether the window's tracking job smooths each tracked bone's
        poses once the run is complete (not a tracker option: :class:`app.tracking_actions.TrackingActions`'
        ``smooth``)."""
        return self.smooth_after.isChecked()

    def accept(self) -> None:
        """OK: the options must be valid (the error names the option and its range), else the
        dialog stays open."""
        try:
            self.options()
        except ValueError as exc:
            from . import errors

            if not errors.report_elsewhere("Tracking options", str(exc)):
                QtWidgets.QMessageBox.warning(self, "Tracking options", str(exc))
            return
        super().accept()
