"""Tracking from the window: a background job per request, progress, cancel, live results.

*Tracking → Track selected bone* (``Ctrl+T``) or *Track all bones* runs
:func:`core.tracking.from_study.track_study` on the open study in the worker pool, over all
frames, starting from the bones' keyframes; the review actions (:mod:`app.review_actions`) run it
over part of the trial (forward or backward from a frame, or between two keyframes). Every
registered frame is written to the trial's journal by the tracker itself as it finishes, and
handed to the window's review data at once (the frame table, plots and timeline fill in while the
job runs); the status bar shows the frame, frames per second and the time left. When the job ends
(done, cancelled or failed) the window reloads the poses and review state from the journal and
lists the flagged frames with their reasons. Tracked bones are locked against edits while the job
runs.

With *Smooth the poses afterwards* ticked in *Tracking options…* (:attr:`TrackingActions.smooth`, off
by default; ``talus track --smooth``) the job, once its run is complete, also smooths the tracked
bones' poses over the trial (:func:`core.tracking.smoothing_trial.smooth_trial`) into
``results/reports/smoothing/<trial>.json``, the status bar saying so meanwhile. A run stopped or
cancelled is not smoothed, nor one cancelled while smoothing (the report is written only after the
last bone, if the job was not cancelled meanwhile); the journal's poses stay the results.

*Tracking → Track in batch…* hands the study's tracking to a Dask batch instead (local cluster or
a given scheduler) and follows it: :mod:`app.batch_panel`.
"""

from __future__ import annotations

import queue
import time

__all__ = ["TrackingActions", "check_batch_available", "smooth_after"]

KEY = "tracking"
#: Flagged frames named one by one in the messages after a run (the rest counted): the trajectory
#: check flags about 5 % of bone-frames of a clean trial, hundreds on a long one.
MAX_FLAG_MESSAGES = 10


def _clock(seconds: float) -> str:
    s = round(seconds)
    return f"{s // 3600}:{s // 60 % 60:02d}:{s % 60:02d}" if s >= 3600 else f"{s // 60}:{s % 60:02d}"


def check_batch_available() -> None:
    """Raise a clear error when Dask distributed (the ``batch`` extra) is not installed."""
    import importlib.util

    if importlib.util.find_spec("distributed") is None:
        raise ValueError("batch: tracking in batch needs Dask distributed, which is not installed: "
                         "pip install 'talus-biplane[batch]'")


class TrackingActions:
    def __init__(self, window) -> None:
        self.window = window
        self.batch = None  # app.batch_panel.BatchPanel, made on first use
        self.batch_action = None
        self.options = None  # core.tracking TrackingOptions (None: the engine's defaults)
        self.smooth = False  # Tracking options' "Smooth the poses afterwards" (talus track --smooth)
        self._notes: queue.SimpleQueue = queue.SimpleQueue()  # status-bar lines from the worker
        self.options_action = None
        self._bones: list[str] = []
        self._was_locked: dict[str, bool] = {}
        self._results: queue.SimpleQueue = queue.SimpleQueue()  # (FrameResult dict, pose) from the worker
        self._t0 = 0.0
        self._frames_total = 0
        self._frames_seen: set[int] = set()
        self.last_feedback = ""
        window.pool.finished.connect(self._on_finished)
        window.pool.failed.connect(lambda key, text: key == KEY and self._on_failed())
        window.pool.cancelled.connect(lambda key: key == KEY and self._on_cancelled())
        window.pool.progress.connect(lambda key, d, t: key == KEY and self.drain_results())

    @property
    def running(self) -> bool:
        return bool(self._bones)

    def add_batch_action(self, menu) -> None:
        """Add *Track in batch…* to the window's Tracking menu."""
        self.batch_action = menu.addAction("Track in &batch…")
        self.batch_action.triggered.connect(lambda: self.window._guard(self.track_in_batch))

    def add_options_action(self, menu) -> None:
        """Add *Options…* (search, resolution, similarity, mode, guess, confidence) to the Tracking menu."""
        action = menu.addAction("Tracking &options…")
        action.setShortcut("Ctrl+Alt+T")
        action.triggered.connect(lambda: self.window._guard(self.edit_options))
        self.options_action = action

    def edit_options(self):
        """Open :class:`app.tracking_options.TrackingOptionsDialog`; the options apply to the next
        tracking job started in the window. Returns the (modal) dialog."""
        from .tracking_options import TrackingOptionsDialog

        dialog = TrackingOptionsDialog(self.options, self.window, smooth=self.smooth)
        dialog.accepted.connect(lambda: self._set_options(dialog.options(), smooth=dialog.smooth()))
        dialog.open()
        return dialog

    def _set_options(self, options, *, smooth: bool | None = None) -> None:
        from .commands.track import CHECKS, STAGE_MOVES, check_choices
        from .tracking_options import choices_of

        self.options = options
        if smooth is not None:
            self.smooth = bool(smooth)
        c = choices_of(options)
        res = "full" if c["scale"] == 1 else f"1/{c['scale']:g}"
        gc = ", gradient components" if c["metric"] == "components" else ""
        final = ", likelihood final stage" if c["final"] == "likelihood" else ""
        if c["sequential_subtract"] != "auto" and c["mode"] != "joint":  # --sequential-subtract on|off
            final += f", neighbours {'' if c['sequential_subtract'] == 'on' else 'not '}subtracted"
        if c["joint_rounds"] != 1 and c["mode"] != "sequential":  # --joint-rounds
            final += f", {c['joint_rounds']} joint rounds"
        if c["joint_restart"] and c["mode"] != "sequential":  # --joint-restart
            final += ", joint rounds from the prediction"
        default = check_choices(None)
        after_run = ("trajectory_limit", "backward_limit")  # the checks once a run is complete
        failure = [k for k in CHECKS if k not in STAGE_MOVES and k not in after_run]  # thresholds
        checks = "" if all(c[k] == default[k] for k in failure) else (
            f", checks: collapse {c['collapse_ratio']:g}, motion {c['motion_limit']:g}x (floor "
            f"{c['motion_floor'][0]:g} mm, {c['motion_floor'][1]:g} deg), sigma {c['sigma_limit']:g}x")
        if c["final"] == "likelihood" and any(c[k] != default[k] for k in STAGE_MOVES):  # its move check
            checks += (f", stage move check {c['stage_move_limit']:g}x (at least "
                       f"{c['stage_move_sigmas']:g} sigma, after {c['stage_move_frames']} frames)"
                       f"{', moves kept' if not c['stage_move_reject'] else ''}")
        if c["trajectory_limit"] != default["trajectory_limit"]:  # the post-pass over the trajectory
            checks += (", trajectory check off" if c["trajectory_limit"] is None
                       else f", trajectory check {c['trajectory_limit']:g}x")
        if c["backward_limit"] != default["backward_limit"]:  # the first frame registered again backward
            checks += (", backward check off" if c["backward_limit"] is None
                       else f", backward check {c['backward_limit']:g}x")
        after = ", poses smoothed afterwards" if self.smooth else ""
        self.window.notify(f"Tracking options: {c['search']} search, {res} resolution{gc}, {c['mode']}, "
                           f"{c['guess']} guess{'' if c['confidence'] else ', no confidence'}{final}{checks}"
                           f"{after}")

    def track_in_batch(self):
        """Open the batch dialog (:mod:`app.batch_panel`); returns it."""
        if self.running:
            raise ValueError("tracking: a tracking job is running (cancel it first)")
        if self.batch is None:
            from .batch_panel import BatchPanel

            self.batch = BatchPanel(self.window)
        return self.batch.ask()

    def track_selected(self) -> None:
        m = self.window.model
        if m is None or m.selected < 0:
            raise ValueError("bone: select a bone to track")
        self.start([m.layers[m.selected].name])

    def track_all(self) -> None:
        m = self.window.model
        if m is None:
            raise ValueError("study: open a study first")
        self.start([layer.name for layer in m.layers])

    def start(self, bones: list[str], frames=None) -> None:
        """Track ``bones`` over ``frames`` (frame numbers in tracking order; default all, forward)."""
        session = self.window.session
        if session is None:
            raise ValueError("study: tracking needs a study open for writing")
        session.require_writable("tracking")
        if self.running:
            raise ValueError("tracking: a tracking job is already running (cancel it first)")
        if self.batch is not None and self.batch.running:
            raise ValueError("tracking: a batch is tracking this study (cancel it first)")

        def again() -> None:  # a queued hand edit would be written beside the tracker's records
            self.window._guard(lambda: self.start(bones, frames))

        if session.edits.after_waiting("tracking", again):  # so start once it is saved (<= 1 s)
            self.window.statusBar().showMessage(
                "Tracking starts once the hand edits waiting for their journals are saved (another writer "
                "holds one for a moment)…", 10_000)
            return
        if self.options is not None and self.options.refine_likelihood:
            from .commands.track import final_stage_problem

            problem = final_stage_problem(session.study, session.trial_name)
            if problem:
                raise ValueError(f"Final stage (Tracking options): {problem}")
        from core.tracking.from_study import WINDOW_TRACKING, track_study

        m = self.window.model
        frames = None if frames is None else [int(f) for f in frames]
        self._bones = list(bones)
        for b in bones:  # no hand edits of a bone while the tracker writes its journal
            self._was_locked[b] = m.layers[m.index(b)].locked
            m.set_layer_property(b, "locked", True)
        study, trial = session.study, session.trial_name
        device, options, smooth = self.window.device, self.options, self.smooth
        results, notes = self._results, self._notes
        while not results.empty():
            results.get_nowait()
        while not notes.empty():
            notes.get_nowait()

        def on_progress(progress, done, total, fr):
            results.put((fr.to_dict(), fr.pose))
            progress(done, total)

        def job(progress, cancel):
            res, report = track_study(study, trial, bones, frames, options=options, device=device,
                                      lock_by=WINDOW_TRACKING,
                                      resume=False, progress=lambda d, t, fr: on_progress(progress, d, t, fr),
                                      cancel=cancel)
            if smooth and res is not None and not cancel() and isinstance(report, dict):
                notes.put(f"Smoothing the poses of {', '.join(res.bones)} over the trial…")
                progress(n, n)  # the GUI thread shows the note (drain_results)
                report["smoothed"] = smooth_after(study, trial, list(res.bones), cancel)
            return res, report

        n = m.n_frames if frames is None else len(frames)
        self._t0 = time.monotonic()
        self._frames_total = n
        self._frames_seen = set()
        span = "" if frames is None else f" (frames {frames[0]}–{frames[-1]})"
        self.window.notify(f"Tracking {', '.join(bones)} over {n} frames{span}…")
        self.window.set_feedback(f"Tracking: frame –/{n}")
        self.window.pool.submit(KEY, job)

    def cancel(self) -> None:
        self.window.pool.cancel(KEY)
        if self.batch is not None:
            self.batch.cancel()

    # ------------------------------------------------------------------ live results
    def drain_results(self) -> None:
        """Hand the results finished so far to the review data (GUI thread) and update the
        status bar: frame i/N, frames per second, time left."""
        review = getattr(self.window, "review", None)
        note = None
        while not self._notes.empty():  # the job's phase after its frames (smoothing)
            note = self._notes.get_nowait()
        if note is not None:
            self.last_feedback = note
            self.window.set_feedback(note)
        got = False
        while True:
            try:
                res, pose = self._results.get_nowait()
            except queue.Empty:
                break
            got = True
            self._frames_seen.add(int(res["frame"]))
            if review is not None and review.data is not None:
                review.data.apply_result(res, pose)
        if not got or note is not None:
            return
        done, n = len(self._frames_seen), self._frames_total
        dt = max(time.monotonic() - self._t0, 1e-9)
        fps = done / dt
        eta = (n - done) / fps if fps > 0 else float("inf")
        self.last_feedback = (f"Tracking: frame {done}/{n} · {fps:.2f} frames/s · "
                              f"ETA {_clock(eta) if eta != float('inf') else '–'}")
        self.window.set_feedback(self.last_feedback)

    # ------------------------------------------------------------------ results
    def _reload(self) -> None:
        self.reload_bones(self._bones)

    def reload_bones(self, bones: list[str]) -> None:
        """Show the poses and review state of ``bones`` as the trial's journals hold them."""
        session, m = self.window.session, self.window.model
        trial = session.study.trial(session.trial_name)
        session.recording = False  # these poses come from the journal: don't write them back
        try:
            for b in bones:
                from .session import _fill

                poses, recorded = _fill(trial.poses(b))
                m.set_trajectory(b, poses)
                layer = m.layers[m.index(b)]
                layer.keyframes |= recorded
        finally:
            session.recording = True
        review = getattr(self.window, "review", None)
        if review is not None and review.data is not None:
            review.data.load_journal(trial)

    def _restore(self) -> None:
        m, session = self.window.model, self.window.session
        bones, self._bones = self._bones, []  # done before the layers change (the Locked box asks)
        if session is not None:  # the tracker locked their journals: the window keeps none it isn't writing
            session.let_go(bones)
        for b in bones:
            m.set_layer_property(b, "locked", self._was_locked.get(b, False))
        self.window.set_feedback(None)

    def _on_failed(self) -> None:
        self.drain_results()
        try:
            self._reload()  # whatever was registered before the failure is in the journal
        finally:
            self._restore()

    def _on_finished(self, key: str, result) -> None:
        if key != KEY:
            return
        self.drain_results()
        try:
            self._show(result)
        finally:
            self._restore()

    def _on_cancelled(self) -> None:
        self.drain_results()
        try:
            self._reload()
            self.window.notify("Tracking cancelled; the frames finished so far are saved.")
        finally:
            self._restore()

    def _show(self, result) -> None:
        res, report = result
        self._reload()
        flagged = report.get("flagged", []) if isinstance(report, dict) else []
        for entry in flagged[:MAX_FLAG_MESSAGES]:  # FrameResult.to_dict(): bone, frame, flags, ...
            self.window.notify(f"{entry['bone']} frame {int(entry['frame'])}: " + "; ".join(entry["flags"]))
        if len(flagged) > MAX_FLAG_MESSAGES:
            self.window.notify(f"... and {len(flagged) - MAX_FLAG_MESSAGES} more flagged frames: "
                               "the review panel lists them all")
        summary = report.get("summary", {}) if isinstance(report, dict) else {}
        self.window.notify(
            f"Tracking {summary.get('status', 'done')}: {summary.get('results', 0)} frames, "
            f"{len(flagged)} flagged for review"
            + ("" if res is not None else f" ({report.get('stopped')})"))
        smoothed = report.get("smoothed") if isinstance(report, dict) else None
        if smoothed:
            for b, why in smoothed["skipped"].items():
                self.window.notify(f"{b} not smoothed: {why}")
            if smoothed["bones"]:
                self.window.notify(f"Smoothed poses of {', '.join(smoothed['bones'])} written to "
                                   f"{smoothed['report']} (the journal keeps the tracked poses)")


def smooth_after(study, trial: str, bones: list[str], cancel) -> dict | None:
    """*Smooth the poses afterwards*: ``bones``' poses smoothed over ``trial``
    (:func:`core.tracking.smoothing_trial.smooth_trial`) and the report written, unless ``cancel()``
    reads True once they are smoothed (then nothing is written; None). Returns the report's path
    (relative to the study), the bones smoothed and those skipped with why, as ``talus track
    --smooth``'s summary."""
    from core.tracking.smoothing_trial import REPORT_KIND, smooth_trial

    rep = smooth_trial(study, trial, bones, write=False)
    if cancel():
        return None
    study.write_report(REPORT_KIND, trial, rep)
    return {"report": f"results/reports/{REPORT_KIND}/{trial}.json", "bones": sorted(rep["bones"]),
            "skipped": rep["skipped"]}
