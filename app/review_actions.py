"""Review, fix and export in the window: the frame table and plots docks and the fix loop.

With a study open the window shows (and these actions drive):

* the **Frames** dock (:class:`app.review.FrameTableDock`): a row per frame and bone (score, σ,
  status and reason, edited); sort, filter (e.g. flagged only); selecting a row moves there;
* the **Plots** dock (:class:`app.plots.PlotsDock`): pose, JCS, helical-axis and joint-space
  curves with a cursor at the current frame; a click moves to that frame;
* the **fix loop** (menu *Review*, and the buttons above the table): on a flagged frame drag the
  bone (every hand-set pose is journalled: a keyframe), or mark its current pose a keyframe
  (``K``); then re-track the selected bone forward (``]``) or backward (``[``) from the frame, or
  between the keyframes around it (``Ctrl+B``), in the background. The journal is append-only:
  *Undo fix* (``Ctrl+Alt+Z``) puts back the tracking result a hand fix replaced. A bone locked
  for a tracking job or a batch says who has it (:meth:`ReviewActions.locked_reason`); a fix of a
  bone handed to a batch waits briefly for its journal, the window responsive meanwhile
  (:meth:`app.session.StudySession.hand_edit`, :mod:`app.hand_edits`): the table shows it edited
  once it is journaled;
* **export** (*File → Export…*): poses in every format of :func:`core.study.exports.available_formats`,
  the plots as PNG/SVG/PDF and the one-page trial report (:func:`core.study.report.write_report`).

Frame numbers are 0-based, on screen as in the API.
"""

from __future__ import annotations

from pathlib import Path

from PySide6 import QtCore, QtGui, QtWidgets

__all__ = ["ReviewActions"]


class ReviewActions:
    def __init__(self, window) -> None:
        self.window = window
        self.data = None
        self.table = self.plots = None
        self.table_dock = self.plots_dock = None
        self._connected = []
        mb = window.menuBar()
        file_menu = next(a.menu() for a in mb.actions() if a.text() == "&File")
        self.export_action = QtGui.QAction("&Export…", window)
        self.export_action.setShortcut(QtGui.QKeySequence("Ctrl+E"))
        self.export_action.triggered.connect(lambda: window._guard(self.export_dialog))
        file_menu.insertAction(window.quit_action, self.export_action)
        file_menu.insertSeparator(window.quit_action)
        help_menu = next(a for a in mb.actions() if a.text() == "&Help")
        menu = QtWidgets.QMenu("&Review", window)
        mb.insertMenu(help_menu, menu)
        self.menu = menu
        self.keyframe_action = self._add(menu, "Mark &keyframe", "K", self.mark_keyframe)
        self.forward_action = self._add(menu, "Re-track &forward from this frame", "]",
                                        lambda: self.retrack("forward"))
        self.backward_action = self._add(menu, "Re-track &backward from this frame", "[",
                                         lambda: self.retrack("backward"))
        self.between_action = self._add(menu, "Re-track &between the keyframes around this frame",
                                        "Ctrl+B", lambda: self.retrack("between"))
        self.undo_fix_action = self._add(menu, "&Undo the fix of this frame", "Ctrl+Alt+Z", self.undo_fix)
        menu.addSeparator()
        self.next_flagged_action = self._add(menu, "&Next flagged frame", "N", lambda: self.goto_flagged(1))
        self._add(menu, "&Previous flagged frame", "Shift+N", lambda: self.goto_flagged(-1))

    def _add(self, menu, text, key, fn):
        act = menu.addAction(text)
        act.setShortcut(QtGui.QKeySequence(key))
        act.triggered.connect(lambda _=False: self.window._guard(fn))
        return act

    # ------------------------------------------------------------------ docks
    def attach(self, model, session) -> None:
        """Build the review data and docks for a newly shown model (``session``: the open study
        or None for a bare model)."""
        from .plots import PlotsDock
        from .review import FrameTableDock, ReviewData

        w = self.window
        self.data = ReviewData([layer.name for layer in model.layers], model.n_frames, w)
        if session is not None:
            self.data.load_journal(session.study.trial(session.trial_name))
            session.notify = lambda text, tag=None: w.notify(  # a hand edit not saved
                text, error=True, **({"tag": tag} if tag else {}))
            session.saved = self._on_saved  # a hand edit journaled (at once, or after a wait)
        if getattr(w, "layers", None) is not None:  # the Locked box refuses while a batch has the bone
            w.layers.held_reason = self.held_reason
        self.table = FrameTableDock(self.data, model)
        bar = QtWidgets.QHBoxLayout()
        buttons = (("Key K", self.keyframe_action), ("Track → ]", self.forward_action),
                   ("Track ← [", self.backward_action), ("Between", self.between_action),
                   ("Undo fix", self.undo_fix_action))
        for text, act in buttons:
            btn = QtWidgets.QToolButton()
            btn.setText(text)
            btn.setToolTip(act.text().replace("&", ""))
            btn.clicked.connect(act.trigger)
            bar.addWidget(btn)
        bar.addStretch(1)
        self.table.layout().insertLayout(0, bar)
        self.table_dock = QtWidgets.QDockWidget("Frames", w)
        self.table_dock.setObjectName("frames-dock")
        self.table_dock.setWidget(self.table)
        w.addDockWidget(QtCore.Qt.DockWidgetArea.RightDockWidgetArea, self.table_dock)
        self.plots = PlotsDock(self.data, model)
        self.plots.joint_space_requested.connect(lambda: w._guard(self.request_joint_space))
        self.plots_dock = QtWidgets.QDockWidget("Plots", w)
        self.plots_dock.setObjectName("plots-dock")
        self.plots_dock.setWidget(self.plots)
        # the table on the right over the whole height; the plots under the images, sharing the
        # bottom with the messages (a tab: no room taken until they are looked at)
        w.setCorner(QtCore.Qt.Corner.BottomRightCorner, QtCore.Qt.DockWidgetArea.RightDockWidgetArea)
        w.setCorner(QtCore.Qt.Corner.TopRightCorner, QtCore.Qt.DockWidgetArea.RightDockWidgetArea)
        w.addDockWidget(QtCore.Qt.DockWidgetArea.BottomDockWidgetArea, self.plots_dock)
        w.tabifyDockWidget(self.plots_dock, w.messages_dock)
        self.plots_dock.show()
        self.plots_dock.raise_()
        w.resizeDocks([self.table_dock], [max(340, w.width() // 4)], QtCore.Qt.Orientation.Horizontal)
        w.resizeDocks([self.plots_dock], [max(220, w.height() // 3)], QtCore.Qt.Orientation.Vertical)
        self.data.changed.connect(self._on_review_changed)
        self.data.reset.connect(self._sync_timeline)
        w.timeline.reason_for = self.data.frame_reason
        model.pose_changed.connect(self._on_pose)
        w.pool.finished.connect(self._on_job)
        self._connected = [(model.pose_changed, self._on_pose), (w.pool.finished, self._on_job)]
        self._sync_timeline()

    def detach(self) -> None:
        for signal, slot in self._connected:
            signal.disconnect(slot)
        self._connected = []
        for dock in (self.table_dock, self.plots_dock):
            if dock is not None:
                self.window.removeDockWidget(dock)
                dock.deleteLater()
        self.table_dock = self.plots_dock = self.table = self.plots = None
        self.data = None

    def _sync_timeline(self) -> None:
        tl = self.window.timeline
        if tl is not None and self.data is not None:
            tl.set_status(self.data.frame_status())

    def _on_review_changed(self, _b: int, f: int) -> None:
        tl = self.window.timeline
        if tl is None or self.data is None:
            return
        code = self.data.frame_status_at(f)
        if tl.status[f] != code:
            tl.status[f] = code
            tl.refresh_status()

    def _on_pose(self, bone: int, frame: int) -> None:
        """A pose edit by hand (drag, nudge, undo): a keyframe, or a fix of a tracked frame."""
        s = self.window.session
        m = self.window.model
        if self.data is None or (s is not None and not s.recording) or m.layers[bone].locked:
            return
        if s is not None and s.writable:  # marked once journaled (_on_saved); refused or waiting:
            return  # the table keeps the journal's status
        self.data.mark_edited(bone, frame, m.pose(bone, frame))

    def _on_saved(self, bone: str, frame: int, pose) -> None:
        """A hand edit of ``bone`` at ``frame`` journaled (at once, or once its journal came)."""
        m = self.window.model
        if self.data is not None and m is not None and bone in self.data.bones:
            self.data.mark_edited(self.data.bones.index(bone), frame, pose)

    # ------------------------------------------------------------------ the fix loop
    def _selected(self):
        m, s = self.window.model, self.window.session
        if m is None or s is None:
            raise ValueError("study: open a study first")
        if m.selected < 0:
            raise ValueError("bone: select a bone first")
        return m, s, m.layers[m.selected].name

    def held_reason(self, bone: str) -> str | None:
        """Why ``bone``'s layer may not be unlocked (the Layers dock's *Locked* box), or None:
        handed to the window's batch — from its start until it ends or is cancelled: a fix could
        be overwritten by a range task that has not reached that frame — or tracked by the
        window's tracking job."""
        tracking = self.window.tracking
        batch = tracking.batch
        if batch is not None and bone in getattr(batch, "_bones", ()):
            return (f"{bone} is being tracked by the batch (Batch dock) until it ends or is cancelled; "
                    "it cannot be unlocked meanwhile")
        if tracking.running and bone in getattr(tracking, "_bones", ()):
            return f"{bone} is being tracked here until the tracking ends or is cancelled"
        return None

    def locked_reason(self, bone: str) -> str:
        """Why ``bone``'s layer is locked, for a refused fix: handed to the running batch (its
        tasks track it, then its trajectory check judges its frames; the window takes it back when
        the batch ends), tracked by the window's tracking job, or locked by hand."""
        tracking = self.window.tracking
        batch = tracking.batch
        if batch is not None and batch.running and bone in getattr(batch, "_bones", ()):
            return (f"bone: {bone} is being written by the batch (its tasks track it, then its trajectory "
                    "check judges the frames); the window takes it back when the batch ends: fix it "
                    "then, or cancel the batch (Tracking → Cancel tracking)")
        if tracking.running and bone in getattr(tracking, "_bones", ()):
            return (f"bone: {bone} is being tracked here; fix it when the tracking ends, or cancel it "
                    "(Tracking → Cancel tracking)")
        return f"bone: {bone} is locked (Layers: untick Locked to edit it)"

    def mark_keyframe(self) -> None:
        """Record the selected bone's pose at the current frame as a hand-set pose (a keyframe)."""
        m, s, bone = self._selected()
        s.require_writable("setting a keyframe")
        if m.layers[m.selected].locked:
            raise ValueError(self.locked_reason(bone))
        f, i = m.current_frame, m.selected
        pose = m.pose(bone, f)

        def done() -> None:  # journaled (the bone's journal free, or once it came)
            m.layers[i].keyframes.add(f)
            if self.data is not None:
                self.data.mark_edited(i, f, pose)
            self.window.notify(f"{bone} frame {f}: keyframe set")

        s.hand_edit(bone, lambda: s.study.trial(s.trial_name).record_pose(bone, f, pose), done=done)

    def keyframes(self, bone: str) -> list[int]:
        s = self.window.session
        return sorted(s.study.trial(s.trial_name).results(bone).keyframes)

    def frames_for(self, direction: str, bone: str, frame: int, n_frames: int) -> list[int]:
        """The frames a re-track covers, in tracking order."""
        if direction == "forward":
            return list(range(frame, n_frames))
        if direction == "backward":
            return list(range(frame, -1, -1))
        if direction == "between":
            keys = self.keyframes(bone)
            before = [k for k in keys if k <= frame]
            after = [k for k in keys if k > frame]
            if not before or not after:
                raise ValueError(f"keyframes: {bone} needs a keyframe at or before frame {frame} and one "
                                 f"after it (has {keys})")
            return list(range(before[-1], after[0] + 1))
        raise ValueError(f"direction: expected 'forward', 'backward' or 'between', got {direction!r}")

    def retrack(self, direction: str) -> None:
        """Re-track the selected bone from the current frame (see :meth:`frames_for`)."""
        m, _, bone = self._selected()
        frames = self.frames_for(direction, bone, m.current_frame, m.n_frames)
        self.window.tracking.start([bone], frames)

    def undo_fix(self, bone: str | None = None, frame: int | None = None) -> None:
        """Put back the tracking result that a hand fix of the selected bone at the current frame
        (``bone`` at ``frame`` where given) replaced (the journal keeps it; the fix stays in the
        journal's history too). While an edit of the bone waits for its journal, this waits for it
        (the journal it reads would lack it: the fix to undo may be that edit), the status bar
        saying so."""
        m, s, selected = self._selected()
        bone = selected if bone is None else bone
        f = m.current_frame if frame is None else int(frame)
        s.require_writable("undoing a fix")
        if m.layers[m.index(bone)].locked:  # a bone handed to a batch: its journal is not the window's
            raise ValueError(self.locked_reason(bone))
        # one waiting undo per bone and frame: an undo asked at another frame (or of another bone)
        # meanwhile waits beside it rather than replacing it
        if s.edits.after_waiting(f"undo fix of {bone} at frame {f}",
                                 lambda: self.window._guard(lambda: self.undo_fix(bone, f)), bone=bone):
            self.window.statusBar().showMessage(
                f"Undo fix of {bone} at frame {f}: waiting for its edit to be saved (another writer holds "
                "its journal for a moment)…", 10_000)
            return
        fixed = m.pose(bone, f)
        trial = s.study.trial(s.trial_name)
        recs = trial.results(bone).essential_records().get(f, [])
        tracked = [r for r in recs if r.kind == "tracked"]
        if not tracked or recs[-1].kind != "hand":
            raise ValueError(f"frame {f}: {bone} has no hand fix of a tracked frame to undo")
        rec = tracked[-1]

        def restore() -> None:
            trial.clear_pose(bone, f)
            trial.record_pose(bone, f, rec.pose, score=rec.score, tracking=rec.tracking)

        def done() -> None:  # journaled: the model shows the tracked pose again
            i = m.index(bone)
            if (m.pose(i, f) != fixed).any():  # moved while this waited: that edit, journaled after
                if self.data is not None:  # this one, stays
                    self.data.reload_bone(trial, bone)
                self.window.notify(f"{bone} frame {f}: fix undone (tracking result restored), then the "
                                   "edit made while it waited saved after it")
                return
            s.recording = False
            try:
                m.layers[i].poses[f] = rec.pose
                m.layers[i].keyframes.discard(f)
                m.pose_changed.emit(i, f)
            finally:
                s.recording = True
            if self.data is not None:
                self.data.reload_bone(trial, bone)
            self.window.notify(f"{bone} frame {f}: fix undone (tracking result restored)")

        s.hand_edit(bone, restore, done=done)

    def goto_flagged(self, step: int) -> None:
        m = self.window.model
        if m is None or self.data is None:
            return
        frames = sorted({f for _, f in self.data.flagged()})
        if not frames:
            self.window.notify("No flagged frame")
            return
        cur = m.current_frame
        nxt = [f for f in frames if f > cur] if step > 0 else [f for f in frames if f < cur][::-1]
        m.set_frame((nxt or (frames if step > 0 else frames[::-1]))[0])

    # ------------------------------------------------------------------ joint space
    def request_joint_space(self) -> None:
        """Compute the joints' smallest surface distances in the background (bone surfaces are
        built from the CTs at half resolution)."""
        if self.plots is None or not self.plots.joints:
            raise ValueError("joints: the trial has no joint to measure")
        from core.tracking.bones import bone_model
        from core.tracking.kinematics import min_distance

        m = self.window.model
        joints = self.plots.joints
        volumes = {layer.name: layer.volume for layer in m.layers}
        poses = {b: self.data.poses[i].copy() for i, b in enumerate(self.data.bones)}

        def job(cancel):
            meshes = {}
            out = {}
            for j in joints:
                for b in (j.proximal, j.distal):
                    if b not in meshes:
                        bm = bone_model(volumes[b], name=b, mesh=True, mesh_step=2)
                        meshes[b] = (bm.vertices, bm.faces)
                    if cancel():
                        return None
                out[j.name] = min_distance(meshes[j.proximal], meshes[j.distal], poses[j.proximal],
                                           poses[j.distal])["distance"]
            return out

        self.window.notify("Computing the joint space…")
        self.window.pool.submit("joint-space", job)

    def _on_job(self, key: str, result) -> None:
        if key == "joint-space" and result is not None and self.plots is not None:
            self.plots.set_joint_space(result)
            self.window.notify("Joint space computed")

    # ------------------------------------------------------------------ export
    def export(self, path: str | Path, kind: str):
        """Export to ``path``: ``kind`` a pose format name (:func:`core.study.exports.available_formats`),
        ``"plots"`` (PNG/SVG/PDF by suffix; returns the list of files, one per page for PNG/SVG)
        or ``"report"`` (HTML/PDF by suffix). Returns the path written."""
        s = self.window.session
        if s is None:
            raise ValueError("study: open a study first")
        p = Path(path)
        if kind == "plots":
            return self.plots.export(str(p))
        if kind == "report":
            from core.study.report import write_report

            return write_report(s.study, s.trial_name, p)
        from core.study.exports import export_poses

        return export_poses(s.study.trial(s.trial_name), p, kind)

    def export_dialog(self):
        """The export dialog (:class:`app.export_dialog.ExportDialog`: every format, bones, path),
        shown; returns it."""
        from .export_dialog import ExportDialog

        dlg = ExportDialog(self.window)
        dlg.setAttribute(QtCore.Qt.WidgetAttribute.WA_DeleteOnClose)
        dlg.open()
        self.window.last_dialog = dlg
        return dlg
