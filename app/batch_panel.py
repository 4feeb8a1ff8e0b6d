"""Tracking in batch from the window: a study's tracking handed to Dask, followed in the window.

*Tracking → Track in batch…* opens :class:`BatchDialog`: the study's trials (the window's one
checked), the bones (the selected one, or all), the mode (as ``talus batch --mode``:
*automatic*, the default or the mode of the window's *Tracking options*, makes one task of a
trial whose frames are flatfield-corrected, its bones tracked jointly as ``talus track`` and the
window's own tracking do, and one task per bone of any other trial; *joint* one task per trial;
*sequential* one task per trial, its bones tracked one after another with the others' DRRs
subtracted, as ``talus track --mode sequential``; *one task per bone*, ``--split-bones``: each
bone searched alone, nothing subtracted), optionally one task per frame range between the
keyframes, and where to
run — a local Dask cluster of N worker processes on this computer (one per GPU, else per CPU
core) or an existing scheduler's cluster (``tcp://host:8786``; its workers must see the study
folder at the same path). *Start* builds the tasks of
:func:`core.tracking.batch.build_tasks` and runs :func:`core.tracking.batch.run_batch` — what
``talus batch`` runs — off the GUI thread (:class:`BatchPanel`):

* the window locks the handed bones of its trial against edits (their layers' *Locked* box
  ticked and disabled, its tooltip saying the batch has the bone until it ends or is cancelled) —
  it holds no journal it is not writing (:mod:`app.session`), so the workers can write them; when
  the batch ends it gives the layers back;
* the **Batch** dock lists every task with its state, a progress bar of its frames, its last
  score and what its searches did with the other bones (*Neighbours*: joint, sequential, one
  bone while it runs; once it ends, from its record, e.g. *sequential, subtracted* — the
  ``sequential_subtract`` choice that ran, auto resolved — its tooltip the record's note, such as
  a task of one bone having nothing to subtract; *joint, 2 rounds* where a joint task runs more
  than the default one round, the *Tracking options*' ``joint_rounds`` (the tooltip gives the
  rounds always), *restart* where its rounds after the first start from the prediction,
  ``joint_restart``); the
  status bar shows the tasks and frames done of all; each task's start and end, and the
  summary, go to the messages;
* *Cancel* (in the dock, or *Tracking → Cancel tracking*) stops the batch: tasks not started are
  dropped, running ones stop at their next registration; every frame finished is in the journal;
* at the end the window reloads the poses and review state of its trial from the journals, and
  the messages give each task's flagged frames — for the frame ranges of a trial's bone, the
  counts after the trajectory check that judges them together once all are done, and the frames
  that check changed (the first 10 named with their flags, the rest counted), as a single run
  names its flagged frames; a check that failed, or the merge of the keyframe two ranges share
  that failed where the check did not judge them (``shared_error``), is an error message (the
  Messages dock comes to the front), in the words ``talus batch`` prints;
* with *Tracking options*' *Smooth the poses afterwards* ticked, each trial whose tasks all complete
  is then smoothed (``talus batch --smooth``, :mod:`app.commands.batch_smooth`; not after a cancel).

Worker events reach the GUI thread through a queue drained by a timer (no Qt call from the
batch's thread).
"""

from __future__ import annotations

import dataclasses
import os
import queue
import threading
import traceback

from PySide6 import QtCore, QtWidgets

__all__ = ["MODES", "BatchDialog", "BatchPanel"]

#: (label, mode of core.tracking.batch.build_tasks) pairs the dialog offers, the default first;
#: ``"split"`` is mode ``"sequential"`` with ``split_bones`` (``talus batch --split-bones``).
MODES = (("Automatic (joint where the frames are flatfield-corrected)", "auto"),
         ("Joint (one task per trial, its bones together)", "joint"),
         ("Sequential (one task per trial, each bone with the others subtracted)", "sequential"),
         ("One task per bone (each searched alone, nothing subtracted)", "split"))

#: The Batch dock's columns; :data:`NEIGHBOURS` is what a task's searches did with the other bones.
COLUMNS = ("Task", "State", "Frames", "Score", "Neighbours")
NEIGHBOURS = COLUMNS.index("Neighbours")


#: The *Neighbours* tooltip's words of a joint task whose rounds after the first start from the
#: prediction (``TrackingOptions.joint_restart``, *Restart joint rounds from the prediction*).
RESTART_TIP = "Rounds after the first start each bone from its prediction (Tracking options)"


def neighbours_text(task, record: dict | None = None, *, restart: bool = False,
                    rounds: int = 1) -> tuple[str, str]:
    """``(text, tooltip)`` of a task's *Neighbours* cell: from its record (or end event) once it
    ran — the mode and the ``sequential_subtract`` choice that ran, the record's note as the
    tooltip — else what the task will do (joint, sequential, one bone). A joint task's cell says
    ``N rounds`` where it runs more than one round a frame (``joint_rounds``) and ``restart`` where its
    rounds after the first start from the prediction (``joint_restart``): the record's once it has
    them, else ``rounds`` and ``restart``, the batch's choices; the tooltip says the rounds, and the
    record's ``joint_restart_note`` (a task resumed with other ones)."""
    if record is not None and record.get("joint_restart") is not None:
        restart = bool(record["joint_restart"])
    if record is not None and record.get("joint_rounds") is not None:
        rounds = int(record["joint_rounds"])
    joint_tip = (f"Tracked jointly, {rounds} round{'s' if rounds != 1 else ''} a frame: each bone with its "
                 f"neighbours' DRRs subtracted")
    more = f", {rounds} rounds" if rounds != 1 else ""
    if restart:
        joint_tip += ". " + RESTART_TIP
    if record is not None and record.get("joint_restart_note"):
        joint_tip += f" ({record['joint_restart_note']})"
    if record is not None and record.get("mode") is not None:
        if record["mode"] == "joint":
            return "joint, subtracted" + more + (", restart" if restart else ""), joint_tip
        used = record.get("sequential_subtract")
        if used is not None:
            tip = record.get("sequential_subtract_note") or (
                "Each bone searched with the other bones' DRRs subtracted" if used else
                "Each bone searched against the whole image (its neighbours' projections in it)")
            return f"sequential, {'subtracted' if used else 'not subtracted'}", tip
    if len(task.bones) == 1:
        return "one bone", "A task of one bone: no neighbour to subtract"
    if task.tracking_mode == "joint":
        return "joint" + more + (", restart" if restart else ""), joint_tip
    return "sequential", ("One bone after another; whether the others are subtracted "
                          "(Tracking options) is decided when the task runs")


def default_workers() -> int:
    """Local workers offered by default: one per GPU Warp sees, else one per CPU core."""
    from core.tracking.batch_dask import gpu_count

    return gpu_count() or os.cpu_count() or 1


class BatchDialog(QtWidgets.QDialog):
    """What to track in batch, and where (see the module notes)."""

    def __init__(self, parent, *, trials: list[str], current_trial: str, bones: list[str],
                 selected: list[str], workers: int, mode: str = "auto") -> None:
        super().__init__(parent)
        self.setObjectName("batch-dialog")
        self.setWindowTitle("Track in batch")
        form = QtWidgets.QVBoxLayout(self)
        what = QtWidgets.QGroupBox("Tasks")
        grid = QtWidgets.QFormLayout(what)
        self.trial_boxes = self._boxes(grid, "Trials:", trials, [current_trial])
        self.bone_boxes = self._boxes(grid, "Bones:", bones, selected)
        self.mode_combo = QtWidgets.QComboBox()
        self.mode_combo.setObjectName("batch-mode")
        for label, value in MODES:
            self.mode_combo.addItem(label, value)
        self.mode_combo.setCurrentIndex(max(0, self.mode_combo.findData(mode)))
        self.mode_combo.setToolTip(
            "As talus track: a trial whose frames are flatfield-corrected by a saved calibration is "
            "tracked jointly — each bone with its neighbours' DRRs subtracted, which a task of one "
            "bone cannot do — in one task; the bones of any other trial one task each. Sequential: "
            "a trial's bones one after another in one task, the others subtracted; one task per bone "
            "spreads a trial over more workers but subtracts nothing")
        grid.addRow("&Mode:", self.mode_combo)
        self.ranges_box = QtWidgets.QCheckBox("One task per frame range between keyframes")
        self.ranges_box.setToolTip("Each bone's frames split at its keyframes: the ranges of one "
                                   "bone are tracked side by side on different workers")
        grid.addRow(self.ranges_box)
        form.addWidget(what)
        where = QtWidgets.QGroupBox("Run on")
        grid = QtWidgets.QGridLayout(where)
        self.local_radio = QtWidgets.QRadioButton("A local cluster on this computer, workers:")
        self.local_radio.setChecked(True)
        self.workers_spin = QtWidgets.QSpinBox()
        self.workers_spin.setRange(1, 256)
        self.workers_spin.setValue(max(1, int(workers)))
        self.scheduler_radio = QtWidgets.QRadioButton("The Dask scheduler at:")
        self.scheduler_edit = QtWidgets.QLineEdit()
        self.scheduler_edit.setMinimumWidth(260)
        self.scheduler_edit.setPlaceholderText("tcp://host:8786")
        self.scheduler_edit.setToolTip("Its workers must see the study folder at the same path")
        grid.addWidget(self.local_radio, 0, 0)
        grid.addWidget(self.workers_spin, 0, 1)
        grid.addWidget(self.scheduler_radio, 1, 0)
        grid.addWidget(self.scheduler_edit, 1, 1)
        form.addWidget(where)
        self.note = QtWidgets.QLabel()
        self.note.setWordWrap(True)
        self.note.setObjectName("batch-dialog-note")
        form.addWidget(self.note)
        buttons = QtWidgets.QDialogButtonBox()
        self.start_button = buttons.addButton("Start", QtWidgets.QDialogButtonBox.ButtonRole.AcceptRole)
        self.cancel_button = buttons.addButton(QtWidgets.QDialogButtonBox.StandardButton.Cancel)
        buttons.accepted.connect(self._accept)
        buttons.rejected.connect(self.reject)
        form.addWidget(buttons)
        for w in (*self.trial_boxes.values(), *self.bone_boxes.values()):
            w.toggled.connect(self._check)
        self.local_radio.toggled.connect(self._check)
        self.scheduler_edit.textChanged.connect(self._check)
        self.scheduler_edit.textEdited.connect(lambda _: self.scheduler_radio.setChecked(True))
        self._check()

    @staticmethod
    def _boxes(form: QtWidgets.QFormLayout, label: str, names: list[str], checked: list[str]) -> dict:
        col = QtWidgets.QVBoxLayout()
        boxes = {}
        for n in names:
            boxes[n] = box = QtWidgets.QCheckBox(n)
            box.setChecked(n in checked)
            col.addWidget(box)
        form.addRow(label, col)
        return boxes

    def choice(self) -> dict:
        """``trials``, ``bones``, ``mode``, ``split_bones``, ``ranges``, and ``workers`` or
        ``scheduler`` (the other None)."""
        local = self.local_radio.isChecked()
        mode = self.mode_combo.currentData()
        return {
            "trials": [t for t, b in self.trial_boxes.items() if b.isChecked()],
            "bones": [t for t, b in self.bone_boxes.items() if b.isChecked()],
            "mode": "sequential" if mode == "split" else mode,
            "split_bones": mode == "split",
            "ranges": self.ranges_box.isChecked(),
            "workers": self.workers_spin.value() if local else None,
            "scheduler": None if local else self.scheduler_edit.text().strip(),
        }

    def _problem(self) -> str:
        c = self.choice()
        if not c["trials"]:
            return "Check a trial to track."
        if not c["bones"]:
            return "Check a bone to track."
        if c["scheduler"] is not None and not c["scheduler"]:
            return "Give the scheduler's address (tcp://host:8786), or run on a local cluster."
        return ""

    def _check(self, *_) -> None:
        problem = self._problem()
        self.note.setText(problem or "The frames tracked go to the study's journals as they finish; "
                                     "a batch run again carries on where it was.")
        self.start_button.setEnabled(not problem)

    def _accept(self) -> None:
        if not self._problem():
            self.accept()


class BatchPanel(QtCore.QObject):
    """Runs a batch for the window and shows its progress (see the module notes)."""

    event = QtCore.Signal(object)  # each worker event, once shown (GUI thread)
    finished = QtCore.Signal(object)  # the summary (core.tracking.batch.summarize) or {"error": text}

    POLL_MS = 100

    def __init__(self, window) -> None:
        super().__init__(window)
        self.window = window
        self.dialog: BatchDialog | None = None
        self.dock: QtWidgets.QDockWidget | None = None
        self.summary: dict | None = None  # the last batch's (core.tracking.batch.summarize)
        self._events: queue.SimpleQueue = queue.SimpleQueue()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._rows: dict[str, int] = {}
        self._tasks: dict = {}
        self._restart = False  # the batch's joint_restart (its joint tasks' rounds from the prediction)
        self._rounds = 1  # the batch's joint_rounds
        self._frames: dict[str, tuple[int, int]] = {}
        self._ended: set[str] = set()
        self._bones: list[str] = []  # the window's trial's bones handed to the batch
        self._was_locked: dict[str, bool] = {}
        self._timer = QtCore.QTimer(self)
        self._timer.setInterval(self.POLL_MS)
        self._timer.timeout.connect(self.drain)
        self.status = QtWidgets.QLabel()
        self.status.setObjectName("batch-status")
        self.bar = QtWidgets.QProgressBar()
        self.bar.setMaximumWidth(160)
        for w in (self.status, self.bar):
            window.statusBar().addPermanentWidget(w)
            w.hide()
        window.installEventFilter(self)

    @property
    def running(self) -> bool:
        return self._thread is not None

    # ------------------------------------------------------------------ dialog
    def ask(self) -> BatchDialog:
        """Open the dialog (not blocking); its *Start* starts the batch."""
        from .tracking_actions import check_batch_available
        from .tracking_options import choices_of

        check_batch_available()
        session, m = self.window.session, self.window.model
        if session is None or m is None:
            raise ValueError("study: open a study first")
        if self.running:
            raise ValueError("batch: a batch is running (cancel it first)")
        selected = [m.layers[m.selected].name] if m.selected >= 0 else [layer.name for layer in m.layers]
        dlg = BatchDialog(self.window, trials=list(session.study.trials), current_trial=session.trial_name,
                          bones=[layer.name for layer in m.layers], selected=selected,
                          workers=default_workers(), mode=choices_of(self.window.tracking.options)["mode"])
        dlg.accepted.connect(lambda: self.window._guard(lambda: self.start(**dlg.choice())))
        self.dialog = dlg
        dlg.open()
        return dlg

    # ------------------------------------------------------------------ run
    def start(self, *, trials: list[str], bones: list[str], mode: str = "auto", ranges: bool = False,
              workers: int | None = None, scheduler: str | None = None, split_bones: bool = False) -> None:
        """Build the tasks (:func:`core.tracking.batch.build_tasks`, ``mode``, ``split_bones`` and
        ``ranges`` as there) and run them off the GUI thread (see the module notes)."""
        from core.tracking.batch import TaskSettings, build_tasks, run_batch

        from .commands.batch import mode_note
        from .commands.track import final_stage_problem

        session, m = self.window.session, self.window.model
        if session is None or not session.writable:
            raise ValueError("study: tracking needs a study open for writing")
        if self.running or self.window.tracking.running:
            raise ValueError("tracking: a tracking job is running (cancel it first)")
        # a hand edit journaled once handed over could be overtaken: start once it is saved
        again = dict(trials=trials, bones=bones, mode=mode, ranges=ranges, workers=workers,
                     scheduler=scheduler, split_bones=split_bones)
        if session.edits.after_waiting("batch", lambda: self.window._guard(lambda: self.start(**again))):
            self.window.statusBar().showMessage(
                "The batch starts once the hand edits waiting for their journals are saved (another writer "
                "holds one for a moment)…", 10_000)
            return
        opts = self.window.tracking.options
        tasks = build_tasks([session.folder], trials, bones, mode=mode, ranges=ranges,
                            split_bones=split_bones,
                            subtract=None if opts is None else opts.sequential_subtract)
        if opts is not None and opts.refine_likelihood:  # as talus batch --final likelihood
            problems = [p for t in sorted({k.trial for k in tasks})
                        if (p := final_stage_problem(session.study, t))]
            if problems:
                raise ValueError("Final stage (Tracking options): " + "; ".join(problems))
        options = () if opts is None else tuple(
            (f.name, getattr(opts, f.name)) for f in dataclasses.fields(opts) if f.init and f.name != "mode")
        settings = TaskSettings(device=self.window.device, options=options)
        self._restart = bool(opts is not None and opts.joint_restart)
        self._rounds = 1 if opts is None else int(opts.joint_rounds)
        trial = session.trial_name
        self._bones = [b for b in bones if b in session.study.trial(trial).bones] if trial in trials else []
        for b in self._bones:  # the workers write these journals: no edits here meanwhile
            self._was_locked[b] = m.layers[m.index(b)].locked
            m.set_layer_property(b, "locked", True)
            session.study.unlock_journal(trial, b)
        n_frames = {t: session.study.trial(t).n_frames for t in {task.trial for task in tasks}}
        self._show_tasks(tasks, {t.key: len(t.order or range(n_frames[t.trial])) * len(t.bones)
                                 for t in tasks})
        self.summary = None
        self._stop.clear()
        events, stop = self._events, self._stop
        smooth, study = self.window.tracking.smooth, session.study

        def work() -> None:
            try:
                summary = run_batch(tasks, settings, workers=workers, scheduler=scheduler,
                                    on_event=events.put, cancel=stop.is_set,
                                    on_start=lambda info: events.put(dict(info, kind="cluster")))
                if smooth and not stop.is_set():  # Tracking options' Smooth the poses afterwards
                    from .commands.batch_smooth import smooth_trials

                    events.put({"kind": "smoothing"})
                    summary["smoothed"] = smooth_trials(tasks, summary.get("task_records") or (),
                                                        study=study, cancel=stop.is_set)
                events.put({"kind": "done", "summary": summary})
            except BaseException as exc:  # shown in the window; the batch thread never raises
                events.put({"kind": "error", "text": "".join(traceback.format_exception(exc)).rstrip()})

        where = scheduler or f"a local cluster of {workers or 'default'} workers"
        self.window.notify(f"Batch: {len(tasks)} tasks on {where}; {mode_note(tasks, mode)}…")
        self._thread = threading.Thread(target=work, name="talus-batch", daemon=True)
        self._thread.start()
        self._timer.start()

    def cancel(self) -> None:
        """Stop the batch (the frames finished stay in the journals)."""
        if self.running and not self._stop.is_set():
            self._stop.set()
            self.window.notify("Batch: cancelling…")
            self.cancel_button.setEnabled(False)

    # ------------------------------------------------------------------ progress
    def _show_tasks(self, tasks, totals: dict[str, int]) -> None:
        if self.dock is None:
            self.dock = QtWidgets.QDockWidget("Batch", self.window)
            self.dock.setObjectName("batch-dock")
            body = QtWidgets.QWidget()
            lay = QtWidgets.QVBoxLayout(body)
            lay.setContentsMargins(4, 4, 4, 4)
            self.table = QtWidgets.QTableWidget(0, len(COLUMNS))
            self.table.setObjectName("batch-tasks")
            self.table.setHorizontalHeaderLabels(list(COLUMNS))
            self.table.verticalHeader().hide()
            self.table.setEditTriggers(QtWidgets.QAbstractItemView.EditTrigger.NoEditTriggers)
            header = self.table.horizontalHeader()
            header.setSectionResizeMode(0, QtWidgets.QHeaderView.ResizeMode.Stretch)
            for c, w in ((1, 150), (2, 140), (3, 60), (NEIGHBOURS, 190)):
                header.resizeSection(c, w)
            lay.addWidget(self.table)
            row = QtWidgets.QHBoxLayout()
            self.where = QtWidgets.QLabel()
            self.where.setTextInteractionFlags(QtCore.Qt.TextInteractionFlag.TextSelectableByMouse)
            self.cancel_button = QtWidgets.QPushButton("Cancel batch")
            self.cancel_button.setObjectName("batch-cancel")
            self.cancel_button.clicked.connect(self.cancel)
            row.addWidget(self.where, 1)
            row.addWidget(self.cancel_button)
            lay.addLayout(row)
            self.dock.setWidget(body)
            self.window.addDockWidget(QtCore.Qt.DockWidgetArea.BottomDockWidgetArea, self.dock)
        self.dock.show()
        self.dock.raise_()
        self.where.setText("Starting the cluster…")
        self.cancel_button.setEnabled(True)
        self.table.setRowCount(len(tasks))
        self._rows = {t.key: i for i, t in enumerate(tasks)}
        self._tasks = {t.key: t for t in tasks}
        self._frames = {t.key: (0, totals[t.key]) for t in tasks}
        self._ended = set()
        for i, t in enumerate(tasks):
            self.table.setItem(i, 0, QtWidgets.QTableWidgetItem(t.key))
            self.table.setItem(i, 1, QtWidgets.QTableWidgetItem("waiting"))
            bar = QtWidgets.QProgressBar()
            bar.setRange(0, max(totals[t.key], 1))
            bar.setValue(0)
            bar.setFormat(f"0/{totals[t.key]}")
            self.table.setCellWidget(i, 2, bar)
            self.table.setItem(i, 3, QtWidgets.QTableWidgetItem(""))
            self.table.setItem(i, NEIGHBOURS, QtWidgets.QTableWidgetItem())
            self._show_neighbours(t.key)
        for w in (self.status, self.bar):
            w.show()
        self._overall()

    def task_state(self, key: str) -> tuple[str, str]:
        """``(state, frames text)`` of a task's row (for tests and scripts)."""
        i = self._rows[key]
        return self.table.item(i, 1).text(), self.table.cellWidget(i, 2).text()

    def task_neighbours(self, key: str) -> tuple[str, str]:
        """``(text, tooltip)`` of a task's *Neighbours* cell (for tests and scripts)."""
        item = self.table.item(self._rows[key], NEIGHBOURS)
        return item.text(), item.toolTip()

    def _show_neighbours(self, key: str, record: dict | None = None) -> None:
        text, tip = neighbours_text(self._tasks[key], record, restart=self._restart, rounds=self._rounds)
        item = self.table.item(self._rows[key], NEIGHBOURS)
        item.setText(text)
        item.setToolTip(tip)

    def _overall(self) -> None:
        done = sum(d for d, _ in self._frames.values())
        total = sum(t for _, t in self._frames.values())
        n = len(self._rows)
        self.bar.setRange(0, max(n, 1))
        self.bar.setValue(len(self._ended))
        self.bar.setFormat("batch %v/%m tasks")
        self.status.setText(f"Batch: {len(self._ended)}/{n} tasks, {done}/{total} frames")

    def drain(self) -> None:
        """Apply the batch's events that arrived (GUI thread)."""
        while True:
            try:
                e = self._events.get_nowait()
            except queue.Empty:
                break
            kind, key = e.get("kind"), e.get("key")
            row = self._rows.get(key)
            if kind == "cluster":
                n = e["workers"]
                self.where.setText(f"{n} worker{'s' if n != 1 else ''} · scheduler {e['scheduler']} · "
                                   f"dashboard {e['dashboard']}")
                self.window.notify(f"Batch: Dask dashboard {e['dashboard']}")
            elif kind == "start" and row is not None:
                self.table.item(row, 1).setText(f"running (pid {e.get('pid')})")
                self.window.notify(f"Batch: {key} started on {e.get('host')} (pid {e.get('pid')})")
            elif kind == "frame" and row is not None:
                done, total = int(e["done"]), int(e["total"])
                self._frames[key] = (done, total)
                bar = self.table.cellWidget(row, 2)
                bar.setRange(0, max(total, 1))
                bar.setValue(done)
                bar.setFormat(f"{done}/{total}")
                if e.get("score") is not None:
                    self.table.item(row, 3).setText(f"{e['score']:.3f}")
                self._overall()
            elif kind == "end" and row is not None:
                self._ended.add(key)
                self.table.item(row, 1).setText(str(e.get("status")))
                self._show_neighbours(key, e)  # what ran: sequential_subtract, joint_rounds, joint_restart
                self.window.notify(f"Batch: {key} {e.get('status')} in {e.get('seconds', 0.0):.1f} s")
                self._overall()
                task, session = self._tasks[key], self.window.session
                shown = [b for b in task.bones if b in self._bones]
                if shown and session is not None and task.trial == session.trial_name:
                    self.window.tracking.reload_bones(shown)  # the window's trial: show it now
            elif kind == "smoothing":
                self.where.setText("Smoothing the poses over the trials…")
            elif kind in ("done", "error"):
                self._finish(e)
                continue
            self.event.emit(e)

    def _finish(self, e: dict) -> None:
        from core.tracking.batch_pass import pass_messages

        from .tracking_actions import MAX_FLAG_MESSAGES

        self._timer.stop()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
        self._thread = None
        self.cancel_button.setEnabled(False)
        try:
            self._take_back()
        finally:
            for w in (self.status, self.bar):
                w.hide()
        if e["kind"] == "error":
            self.where.setText("The batch failed")
            self.window.notify(f"Batch failed:\n{e['text']}", error=True)
            self.finished.emit({"error": e["text"]})
            return
        s = self.summary = e["summary"]
        passes = s.get("trajectory_pass") or []
        judged = {k for p in passes for k in (p.get("tasks_flagged") or {})}  # told per trial below
        for r in s["task_records"]:
            row = self._rows.get(r["key"])
            if row is not None:  # a range's count after the trial's trajectory check
                self._show_neighbours(r["key"], r)
                self.table.item(row, 1).setText(
                    r["status"] + (f", {r['flagged']} flagged" if r.get("flagged") else "")
                    + (f" ({r['attempts']} attempts)" if r.get("attempts", 1) > 1 else ""))
            if r.get("flagged") and r["key"] not in judged:
                self.window.notify(f"Batch: {r['key']}: {r['flagged']} frames flagged for review")
        for p in passes:  # the final counts of each trial's bone(s) over its ranges, and what changed
            # an error: the check failed (``error``), or, in a group not judged, the merge of the keyframe
            # its ranges share (``shared_error``); the same lines as talus batch prints
            failed = bool(p.get("error") or p.get("shared_error"))
            for line in pass_messages(p, limit=MAX_FLAG_MESSAGES):
                self.window.notify(f"Batch: {line}", error=failed)
        from .commands.batch_smooth import smooth_lines

        for line in smooth_lines(s.get("smoothed") or ()):
            self.window.notify(f"Batch: {line}")
        for f in s["failures"]:
            self.window.notify(f"Batch: {f['key']} failed after {f['attempts']} attempts: {f['error']}",
                               error=True)
        self.where.setText(f"Batch {s['status']}: {s['tasks_complete']}/{s['tasks']} tasks complete, "
                           f"{s['frames_tracked']} frames tracked in {s['wall_s']:.1f} s")
        self.window.notify(self.where.text())
        self.finished.emit(s)

    def _take_back(self) -> None:
        """Unlock the handed bones' layers (their journals free: checked, not kept) and show what
        the batch wrote."""
        from core.io.atomic import LockedError

        session, m = self.window.session, self.window.model
        bones, self._bones = self._bones, []
        if session is None or m is None or not bones:
            return
        held = []
        for b in bones:
            try:  # the window takes a journal per edit only (app.session): let it go at once
                session.study.lock_journal(session.trial_name, b)
                session.study.unlock_journal(session.trial_name, b)
            except LockedError as exc:  # a worker of another cluster still writes it
                held.append(b)
                self.window.notify(f"Batch: {b} is still being written elsewhere ({exc}); "
                                   "it stays locked here")
        self.window.tracking.reload_bones(bones)
        for b in bones:
            if b not in held:
                m.set_layer_property(b, "locked", self._was_locked.get(b, False))
        if getattr(self.window, "layers", None) is not None:  # the Locked box: the batch has let go
            self.window.layers.refresh_locks()

    # ------------------------------------------------------------------ window closing
    def eventFilter(self, obj, event) -> bool:
        if obj is self.window and event.type() == QtCore.QEvent.Type.Close and self.running:
            self._stop.set()  # the window goes: stop the batch (frames done are saved)
            if self._thread is not None:
                self._thread.join(timeout=30.0)
            self._timer.stop()
            self._thread = None
        return False
