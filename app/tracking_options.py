"""Tracking > Options…: the choices ``talus track`` offers on its command line, in the window.

The dialog edits the window's :class:`core.tracking.trial.TrackingOptions` (``TrackingActions.options``)
through :func:`options_from_choices` — defined in :mod:`app.commands.track` and used by ``talus
track`` itself for ``--search``, ``--scale``, ``--metric``, ``--mode``, ``--guess``, ``--final`` and
``--no-confidence``, so the two cannot drift:

* **Search** — *local* (fitted quadratic models, the default) or *Gauss–Newton* (the faster
  engine: pose derivatives from one launch per iteration);
* **Resolution** — full, ½ or ¼: the pyramid scale of a tracked frame's last level (detector
  pixels per DRR pixel). Reduced resolution is several times faster, chiefly without a GPU;
* **Similarity** — the gradient correlation of the gradient magnitudes (the default) or of the
  gradient components (Penney's form: better on overlapping bones in the harder synthetic trial,
  slower);
* **Mode** — automatic (the default, as ``talus track``: jointly when the trial's frames are
  flatfield-corrected, else one after the other), bones one after the other, or jointly (each
  with the others' DRRs subtracted);
* **Guess** — the next frame's start: velocity, previous pose or a spline through the track;
* **Final stage** — none (the default) or *likelihood*: every registration ends with a weighted
  least-squares refinement of the pose against the line-integral image
  (``TrackingOptions.refine_likelihood``). On the synthetic 1024² walking trial (one NVIDIA H200)
  it brought the talus closer to its Cramér–Rao bound and improved every bone's rotation, but
  worsened the tibia's and calcaneus's translation in joint mode, for +11.6 ms per bone-frame
  (+107 ms per joint frame). It needs flatfield-corrected frames: a trial without a flatfield
  correction is refused when the job starts (:func:`app.commands.track.final_stage_problem`);
* **Confidence** — the pose uncertainty of every frame (costs a few renders per frame).
"""

from __future__ import annotations

from PySide6 import QtWidgets

from .commands.track import choices_of, options_from_choices

__all__ = ["FINALS", "METRICS", "RESOLUTIONS", "SEARCHES", "TrackingOptionsDialog", "choices_of",
           "options_from_choices"]

#: (label, search) pairs shown in the dialog.
SEARCHES = (("Local (quadratic models)", "local"), ("Gauss–Newton (faster)", "newton"))
#: (label, final pyramid scale) pairs shown in the dialog.
RESOLUTIONS = (("Full", 1.0), ("½ (4× fewer pixels)", 2.0), ("¼ (16× fewer pixels)", 4.0))
#: (label, ``talus track --metric``) pairs shown in the dialog.
METRICS = (("Gradient magnitudes", "magnitudes"), ("Gradient components", "components"))
_MODES = (("Automatic (joint on flatfield-corrected frames)", "auto"),
          ("Sequential (one bone after another)", "sequential"), ("Joint (bones together)", "joint"))
_GUESSES = (("Velocity", "velocity"), ("Previous pose", "previous"), ("Spline", "spline"))
#: (label, ``talus track --final``) pairs shown in the dialog.
FINALS = (("None", "none"), ("Likelihood refinement (flatfield-corrected frames)", "likelihood"))


def _combo(pairs, value) -> QtWidgets.QComboBox:
    box = QtWidgets.QComboBox()
    for label, v in pairs:
        box.addItem(label, v)
    values = [v for _, v in pairs]
    box.setCurrentIndex(values.index(value) if value in values else 0)
    return box


class TrackingOptionsDialog(QtWidgets.QDialog):
    """Choose search, resolution, similarity, mode, guess, final stage and confidence; :meth:`options`
    gives the result."""

    def __init__(self, options=None, parent=None) -> None:
        super().__init__(parent)
        self.setWindowTitle("Tracking options")
        c = choices_of(options)
        self.search = _combo(SEARCHES, c["search"])
        self.resolution = _combo(RESOLUTIONS, c["scale"])
        self.similarity = _combo(METRICS, c["metric"])  # not "metric": that would hide QPaintDevice.metric()
        self.mode = _combo(_MODES, c["mode"])
        self.guess = _combo(_GUESSES, c["guess"])
        self.final = _combo(FINALS, c["final"])
        self.confidence = QtWidgets.QCheckBox("Pose uncertainty of every frame")
        self.confidence.setChecked(c["confidence"])
        self.search.setToolTip("Gauss–Newton needs fewer renders per frame; first frames and retries "
                               "always search globally")
        self.resolution.setToolTip("Reduced resolution tracks several times faster (chiefly on a CPU), "
                                   "with a larger error")
        self.similarity.setToolTip("Gradient components (Penney's form): better on overlapping bones in the "
                               "harder synthetic trial, slower")
        self.final.setToolTip(
            "Likelihood: every registration ends with a weighted least-squares refinement against the "
            "line-integral image. On the synthetic 1024² trial (one NVIDIA H200): talus alone 2.21/2.15× → "
            "1.47/1.46× its Cramér–Rao bound (mm/°), +11.6 ms per bone-frame; jointly better rotation for "
            "every bone, but tibia and calcaneus translation worse (2.21 → 4.34×, 1.45 → 1.89×), "
            "+107 ms per frame. Needs flatfield-corrected frames.")
        form = QtWidgets.QFormLayout()
        form.addRow("&Search:", self.search)
        form.addRow("&Resolution:", self.resolution)
        form.addRow("S&imilarity:", self.similarity)
        form.addRow("&Mode:", self.mode)
        form.addRow("&Guess:", self.guess)
        form.addRow("&Final stage:", self.final)
        form.addRow("", self.confidence)
        buttons = QtWidgets.QDialogButtonBox(
            QtWidgets.QDialogButtonBox.StandardButton.Ok | QtWidgets.QDialogButtonBox.StandardButton.Cancel
            | QtWidgets.QDialogButtonBox.StandardButton.RestoreDefaults)
        buttons.accepted.connect(self.accept)
        buttons.rejected.connect(self.reject)
        buttons.button(QtWidgets.QDialogButtonBox.StandardButton.RestoreDefaults).clicked.connect(
            self.restore_defaults)
        self.buttons = buttons
        layout = QtWidgets.QVBoxLayout(self)
        layout.addLayout(form)
        layout.addWidget(buttons)

    def restore_defaults(self) -> None:
        for box in (self.search, self.resolution, self.similarity, self.mode, self.guess, self.final):
            box.setCurrentIndex(0)
        self.confidence.setChecked(True)

    def choices(self) -> dict:
        return {"search": self.search.currentData(), "scale": float(self.resolution.currentData()),
                "mode": self.mode.currentData(), "guess": self.guess.currentData(),
                "confidence": self.confidence.isChecked(), "metric": self.similarity.currentData(),
                "final": self.final.currentData()}

    def options(self):
        return options_from_choices(**self.choices())
