"""Tracking from the window: a background job per request, progress, cancel, live results.

*Tracking → Track selected bone* (``Ctrl+T``) or *Track all bones* runs
:func:`core.tracking.from_study.track_study` on the open study in the worker pool, over all
frames, starting from the bones' keyframes. Every registered frame is written to the trial's
journal by the tracker itself as it finishes; when the job ends (done, cancelled or failed) the
window reloads the poses from the journal, marks frames tracked or flagged in the timeline and
lists the flagged frames with their reasons. Tracked bones are locked against edits while the
job runs.
"""

from __future__ import annotations

import numpy as np

__all__ = ["TrackingActions"]

KEY = "tracking"


class TrackingActions:
    def __init__(self, window) -> None:
        self.window = window
        self.options = None  # core.tracking TrackingOptions (None: the engine's defaults)
        self._bones: list[str] = []
        self._was_locked: dict[str, bool] = {}
        window.pool.finished.connect(self._on_finished)
        window.pool.failed.connect(lambda key, text: key == KEY and self._on_failed())
        window.pool.cancelled.connect(lambda key: key == KEY and self._on_cancelled())

    @property
    def running(self) -> bool:
        return bool(self._bones)

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
        session = self.window.session
        if session is None or not session.writable:
            raise ValueError("study: tracking needs a study open for writing")
        if self.running:
            raise ValueError("tracking: a tracking job is already running (cancel it first)")
        from core.tracking.from_study import track_study

        m = self.window.model
        self._bones = list(bones)
        for b in bones:  # no hand edits of a bone while the tracker writes its journal
            self._was_locked[b] = m.layers[m.index(b)].locked
            m.set_layer_property(b, "locked", True)
        study, trial = session.study, session.trial_name
        device, options = self.window.device, self.options

        def job(progress, cancel):
            return track_study(study, trial, bones, frames, options=options, device=device,
                               resume=False, progress=lambda d, t, *_: progress(d, t),
                               cancel=cancel)

        self.window.notify(f"Tracking {', '.join(bones)} over {m.n_frames} frames…")
        self.window.pool.submit(KEY, job)

    def cancel(self) -> None:
        self.window.pool.cancel(KEY)

    # ------------------------------------------------------------------ results
    def _reload(self) -> None:
        session, m = self.window.session, self.window.model
        trial = session.study.trial(session.trial_name)
        status = self.window.timeline.status.copy()
        session.recording = False  # these poses come from the journal: don't write them back
        try:
            for b in self._bones:
                from .session import _fill

                poses, recorded = _fill(trial.poses(b))
                m.set_trajectory(b, poses)
                layer = m.layers[m.index(b)]
                layer.keyframes |= recorded
                status[sorted(recorded)] = np.maximum(status[sorted(recorded)], 2)
        finally:
            session.recording = True
        self.window.timeline.set_status(status)

    def _restore(self) -> None:
        m = self.window.model
        for b in self._bones:
            m.set_layer_property(b, "locked", self._was_locked.get(b, False))
        self._bones = []

    def _on_failed(self) -> None:
        self._reload()  # whatever was registered before the failure is in the journal
        self._restore()

    def _on_finished(self, key: str, result) -> None:
        if key != KEY:
            return
        try:
            self._show(result)
        finally:
            self._restore()

    def _on_cancelled(self) -> None:
        self._reload()
        self.window.notify("Tracking cancelled; the frames finished so far are saved.")
        self._restore()

    def _show(self, result) -> None:
        res, report = result
        self._reload()
        status = self.window.timeline.status.copy()
        flagged = report.get("flagged", []) if isinstance(report, dict) else []
        for entry in flagged:  # FrameResult.to_dict(): bone, frame, flags, ...
            frame = int(entry["frame"])
            status[frame] = 3
            self.window.notify(f"{entry['bone']} frame {frame + 1}: " + "; ".join(entry["flags"]))
        self.window.timeline.set_status(status)
        summary = report.get("summary", {}) if isinstance(report, dict) else {}
        self.window.notify(
            f"Tracking {summary.get('status', 'done')}: {summary.get('results', 0)} frames, "
            f"{len(flagged)} flagged for review"
            + ("" if res is not None else f" ({report.get('stopped')})"))
