"""Results of whole-trial tracking (:func:`core.tracking.trial.track`): one bone in one frame
(:class:`FrameResult`, with its review state as a journal keeps it) and a run
(:class:`TrackingResult`: poses, low-passed trajectories, summary and report)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["FrameResult", "TrackingResult"]


@dataclass(frozen=True, eq=False)
class FrameResult:
    """One bone in one frame: ``pose`` (None when nothing was recorded), ``score``, work done,
    ``converged`` (passed every check), ``flags`` (reasons for review), ``retried``, the
    :class:`~core.tracking.confidence.PoseConfidence` as a dict (or None), the time breakdown
    and ``notes`` (events that needed no review, e.g. a start corrected by restarts). Work and
    time add up every registration of the bone in the frame (both rounds of joint tracking).
    ``search_pose``: the search's pose the final stage started from, where a stage's fit is kept
    (its move taken, or rejected: then ``pose`` is it); None without (``pose`` is the search's).
    Not in :meth:`to_dict` (a journal keeps the pose only)."""

    bone: str
    frame: int
    pose: np.ndarray | None
    score: float
    evaluations: int
    time_s: float
    converged: bool
    flags: tuple[str, ...] = ()
    retried: bool = False
    confidence: dict | None = None
    timing: dict | None = None
    notes: tuple[str, ...] = ()
    search_pose: np.ndarray | None = None

    def to_dict(self) -> dict:
        score = None if not np.isfinite(self.score) else self.score
        return {"bone": self.bone, "frame": self.frame, "score": score,
                "evaluations": self.evaluations, "time_s": self.time_s, "converged": self.converged,
                "flags": list(self.flags), "retried": self.retried, "confidence": self.confidence,
                "timing": self.timing, "notes": list(self.notes)}

    def journal_fields(self) -> dict:
        """The review state a journal keeps beside the pose and score (``tracking`` of
        :meth:`core.study.Trial.record_pose`): everything :meth:`to_dict` holds but bone,
        frame and score."""
        d = self.to_dict()
        for k in ("bone", "frame", "score"):
            d.pop(k)
        return d

    @classmethod
    def from_journal(cls, bone: str, record) -> FrameResult:
        """Rebuild a tracked frame from a journal record (a :class:`core.study.PoseRecord` with
        ``tracking``), exactly as it was reported."""
        t = record.tracking
        if t is None or record.pose is None:
            raise ValueError(f"record: frame {record.frame} of {bone!r} is not a tracking result")
        return cls(bone, int(record.frame), np.asarray(record.pose, float), float(record.score),
                   int(t.get("evaluations", 0)), float(t.get("time_s", 0.0)), bool(t.get("converged", False)),
                   tuple(t.get("flags", ())), bool(t.get("retried", False)), t.get("confidence"),
                   t.get("timing"), tuple(t.get("notes", ())))


@dataclass(frozen=True, eq=False)
class TrackingResult:
    """All frame results of a :func:`~core.tracking.trial.track` run; ``status`` is ``"complete"``
    or ``"cancelled"``."""

    bones: tuple[str, ...]
    frames: tuple[int, ...]
    results: dict
    status: str
    time_s: float

    def poses(self, bone: str) -> np.ndarray:
        """``(len(frames), 4, 4)`` poses of ``bone`` in ``frames`` order, NaN where none."""
        out = np.full((len(self.frames), 4, 4), np.nan)
        for k, f in enumerate(self.frames):
            r = self.results.get((bone, f))
            if r is not None and r.pose is not None:
                out[k] = r.pose
        return out

    def filtered_poses(self, bone: str, frame_rate_hz: float, *, cutoff_hz: float | None = None,
                       center=None, order: int = 2) -> tuple[np.ndarray, float]:
        """Zero-phase low-passed :meth:`poses` of ``bone`` (``frames`` must be consecutive frames
        at ``frame_rate_hz``) and the cut-off used: ``cutoff_hz`` or, when None, Winter's
        residual analysis of the path of ``center`` (bone frame, mm; default the origin). Flagged
        and missing frames are interpolated for the filter and stay NaN."""
        from .kinematics import filter_poses, residual_cutoff

        P = self.poses(bone)
        for k, f in enumerate(self.frames):
            r = self.results.get((bone, f))
            if r is not None and r.flags:
                P[k] = np.nan
        c = np.zeros(3) if center is None else np.asarray(center, float)
        if cutoff_hz is None:
            ok = np.all(np.isfinite(P), axis=(1, 2))
            path = np.full((len(P), 3), np.nan)
            path[ok] = P[ok, :3, :3] @ c + P[ok, :3, 3]
            cutoff_hz, _ = residual_cutoff(path, frame_rate_hz, order=order)
        return filter_poses(P, frame_rate_hz, cutoff_hz, center=c, order=order), float(cutoff_hz)

    @property
    def flagged(self) -> list[FrameResult]:
        return [r for r in self.results.values() if r.flags]

    def summary(self) -> dict:
        rs = list(self.results.values())
        done = [r for r in rs if r.pose is not None]
        return {"status": self.status, "bones": list(self.bones), "frames": len(self.frames),
                "results": len(rs), "recorded": len(done),
                "converged_fraction": float(np.mean([r.converged for r in rs])) if rs else None,
                "flagged": len(self.flagged), "evaluations": int(sum(r.evaluations for r in rs)),
                "time_s": self.time_s,
                "time_per_frame_s": self.time_s / max(len({r.frame for r in rs}), 1)}

    def report(self) -> dict:
        """JSON-ready report: summary and every frame result (flags and reasons included)."""
        return {"summary": self.summary(), "frames": [r.to_dict() for r in self.results.values()]}
