"""Tracking > Options…: the choices ``talus track`` offers on its command line, in the window.

The dialog edits the window's :class:`core.tracking.trial.TrackingOptions` (``TrackingActions.options``)
through :func:`options_from_choices`, the same mapping ``talus track`` uses for ``--search``,
``--scale``, ``--metric``, ``--mode``, ``--guess`` and ``--no-confidence``:

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
* **Confidence** — the pose uncertainty of every frame (costs a few renders per frame).
"""

from __future__ import annotations

from PySide6 import QtWidgets

__all__ = ["METRICS", "RESOLUTIONS", "SEARCHES", "TrackingOptionsDialog", "choices_of",
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


def options_from_choices(search: str = "local", scale: float = 1.0, mode: str = "auto",
                         guess: str = "velocity", confidence: bool = True, metric: str = "magnitudes"):
    """The tracking options ``talus track --search S --scale X --mode M --guess G --metric C`` uses."""
    from core.tracking.register import RegistrationOptions
    from core.tracking.trial import TrackingOptions

    from .commands.track import registration_terms

    reg = RegistrationOptions(terms=registration_terms(metric), bounds=(5.0, 5.0), sigma=(1.0, 1.0),
                              search=search, final_scale=float(scale))
    return TrackingOptions(registration=reg, guess=guess, mode=mode, confidence=bool(confidence))


def choices_of(options) -> dict:
    """The dialog's choices for ``options`` (None: the defaults)."""
    if options is None:
        return {"search": "local", "scale": 1.0, "mode": "auto", "guess": "velocity",
                "confidence": True, "metric": "magnitudes"}
    reg = options.registration
    components = any(t.kind == "gc" and t.options.get("components") for t in reg.terms)
    return {"search": reg.search, "scale": float(reg.final_scale), "mode": options.mode,
            "guess": options.guess, "confidence": bool(options.confidence),
            "metric": "components" if components else "magnitudes"}


def _combo(pairs, value) -> QtWidgets.QComboBox:
    box = QtWidgets.QComboBox()
    for label, v in pairs:
        box.addItem(label, v)
    values = [v for _, v in pairs]
    box.setCurrentIndex(values.index(value) if value in values else 0)
    return box


class TrackingOptionsDialog(QtWidgets.QDialog):
    """Choose search, resolution, similarity, mode, guess and confidence; :meth:`options` gives the result."""

    def __init__(self, options=None, parent=None) -> None:
        super().__init__(parent)
        self.setWindowTitle("Tracking options")
        c = choices_of(options)
        self.search = _combo(SEARCHES, c["search"])
        self.resolution = _combo(RESOLUTIONS, c["scale"])
        self.similarity = _combo(METRICS, c["metric"])  # not "metric": that would hide QPaintDevice.metric()
        self.mode = _combo(_MODES, c["mode"])
        self.guess = _combo(_GUESSES, c["guess"])
        self.confidence = QtWidgets.QCheckBox("Pose uncertainty of every frame")
        self.confidence.setChecked(c["confidence"])
        self.search.setToolTip("Gauss–Newton needs fewer renders per frame; first frames and retries "
                               "always search globally")
        self.resolution.setToolTip("Reduced resolution tracks several times faster (chiefly on a CPU), "
                                   "with a larger error")
        self.similarity.setToolTip("Gradient components (Penney's form): better on overlapping bones in the "
                               "harder synthetic trial, slower")
        form = QtWidgets.QFormLayout()
        form.addRow("&Search:", self.search)
        form.addRow("&Resolution:", self.resolution)
        form.addRow("S&imilarity:", self.similarity)
        form.addRow("&Mode:", self.mode)
        form.addRow("&Guess:", self.guess)
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
        for box in (self.search, self.resolution, self.similarity, self.mode, self.guess):
            box.setCurrentIndex(0)
        self.confidence.setChecked(True)

    def choices(self) -> dict:
        return {"search": self.search.currentData(), "scale": float(self.resolution.currentData()),
                "mode": self.mode.currentData(), "guess": self.guess.currentData(),
                "confidence": self.confidence.isChecked(), "metric": self.similarity.currentData()}

    def options(self):
        return options_from_choices(**self.choices())
