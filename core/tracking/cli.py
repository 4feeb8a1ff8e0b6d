"""``talus track``: track bones of a study trial from the command line.

Usage::

    talus track STUDY --trial T [--bones a,b] [--frames 0:500] [--backward] [--device cuda:0]
                [--resume] [--guess velocity|previous|spline] [--mode sequential|joint]
                [--metric gc] [--no-confidence] [--quiet]

Every registered frame is saved to the study's pose journal as it finishes; the tracking report
(``results/reports/tracking/<trial>.json``) lists per-frame scores and the frames flagged for
review. A progress bar goes to stderr, the JSON summary to stdout. Ctrl-C stops after the
registration in flight (``--resume`` continues later). Exit status: 0 done, 1 bad input, 2 no
bone could be tracked, 130 interrupted.
"""

from __future__ import annotations

import argparse
import json
import signal
import sys
import time

__all__ = ["main", "parse_frames"]


def parse_frames(text: str | None, n_frames: int) -> list[int]:
    """``"a:b"`` (b exclusive; either side may be empty), ``"a"`` or None (all) → frame list."""
    if text is None:
        return list(range(n_frames))
    try:
        if ":" in text:
            a, b = text.split(":", 1)
            lo = int(a) if a.strip() else 0
            hi = int(b) if b.strip() else n_frames
        else:
            lo = int(text)
            hi = lo + 1
    except ValueError:
        raise ValueError(f"--frames: expected START:STOP or a frame number, got {text!r}") from None
    if not 0 <= lo < hi <= n_frames:
        raise ValueError(f"--frames: {text!r} is not a non-empty range inside 0:{n_frames}")
    return list(range(lo, hi))


class _Bar:
    def __init__(self, stream, quiet: bool) -> None:
        self.stream, self.quiet, self.t0 = stream, quiet, time.monotonic()

    def __call__(self, done: int, total: int, fr) -> None:
        if self.quiet:
            return
        w = 30
        k = int(w * done / max(total, 1))
        el = time.monotonic() - self.t0
        eta = el / max(done, 1) * (total - done)
        flag = f"  flagged {fr.bone}@{fr.frame}" if fr.flags else ""
        self.stream.write(f"\r[{'#' * k}{'.' * (w - k)}] {done}/{total} {fr.bone}@{fr.frame} "
                          f"score {fr.score:.3f}  {el:.0f}s, ETA {eta:.0f}s{flag}   ")
        if fr.flags:
            self.stream.write("\n")
        self.stream.flush()

    def close(self) -> None:
        if not self.quiet:
            self.stream.write("\n")
            self.stream.flush()


def main(argv=None) -> int:
    """Run ``talus track`` with ``argv`` (without the program name); returns the exit status."""
    p = argparse.ArgumentParser(prog="talus track", description="Track bones of a study trial.")
    p.add_argument("study", help="study folder (study.json)")
    p.add_argument("--trial", required=True, help="trial name")
    p.add_argument("--bones", default=None, help="comma-separated bone names (default: the trial's bones)")
    p.add_argument("--frames", default=None, help="START:STOP (STOP exclusive; default all frames)")
    p.add_argument("--backward", action="store_true", help="track from the last frame to the first")
    p.add_argument("--device", default=None,
                   help="Warp device: cpu, cuda, cuda:1 (default CUDA when present)")
    p.add_argument("--resume", action="store_true", help="skip frames that already have a pose")
    p.add_argument("--guess", choices=("velocity", "previous", "spline"), default="velocity")
    p.add_argument("--mode", choices=("sequential", "joint"), default="sequential",
                   help="joint: register each bone with the others' DRRs subtracted (needs DRR "
                        "intensities that match the radiographs: flatfield-corrected frames and a "
                        "calibrated HU transfer)")
    p.add_argument("--metric", default="gc", help="similarity metric (a core.similarity batched kind; "
                                                  "gc: both images smoothed by 0.3 mm, the default cost)")
    p.add_argument("--threshold", type=float, default=200.0, help="bone threshold, HU")
    p.add_argument("--no-confidence", action="store_true", help="skip the per-frame uncertainty")
    p.add_argument("--max-uncertainty", default=None, metavar="MM,DEG",
                   help="flag frames for review whose confidence (length of the sigma vector) exceeds "
                        "MM in translation or DEG in rotation, e.g. 0.3,0.6")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    a = p.parse_args(argv)

    from ..study import Study, StudyError
    from .cost import DEFAULT_TERMS, MetricTerm
    from .from_study import track_study
    from .register import RegistrationOptions
    from .trial import TrackingOptions

    stop = {"flag": False}

    def on_sigint(signum, frame):
        stop["flag"] = True

    try:
        study = Study.open(a.study, mode="w")
    except (StudyError, ValueError, OSError) as exc:
        print(f"talus track: {exc}", file=sys.stderr)
        return 1
    old = signal.signal(signal.SIGINT, on_sigint)
    bar = _Bar(sys.stderr, a.quiet)
    try:
        trial = study.trial(a.trial)
        frames = parse_frames(a.frames, trial.n_frames)
        if a.backward:
            frames = frames[::-1]
        bones = a.bones.split(",") if a.bones else None
        terms = DEFAULT_TERMS if a.metric == "gc" else (MetricTerm(a.metric),)
        reg = RegistrationOptions(terms=terms, bounds=(5.0, 5.0), sigma=(1.0, 1.0), search="local")
        limits = None
        if a.max_uncertainty is not None:
            try:
                limits = tuple(float(v) for v in a.max_uncertainty.split(","))
            except ValueError:
                raise ValueError(f"--max-uncertainty: expected MM,DEG (two numbers), got "
                                 f"{a.max_uncertainty!r}") from None
        opts = TrackingOptions(registration=reg, guess=a.guess, mode=a.mode, confidence=not a.no_confidence,
                               max_uncertainty=limits)
        result, report = track_study(study, a.trial, bones, frames, options=opts, device=a.device,
                                     resume=a.resume, threshold_hu=a.threshold, progress=bar,
                                     cancel=lambda: stop["flag"])
    except (StudyError, ValueError) as exc:
        bar.close()
        print(f"talus track: {exc}", file=sys.stderr)
        return 1
    finally:
        signal.signal(signal.SIGINT, old)
        study.close()
    bar.close()
    out = {"trial": a.trial, "summary": report.get("summary"), "stopped": report.get("stopped"),
           "flagged": [(f["bone"], f["frame"], f["flags"]) for f in report.get("flagged", [])],
           "normalisation": report.get("normalisation")}
    sys.stdout.write(json.dumps(out, indent=2) + "\n")
    if result is None:
        return 2
    return 130 if result.status == "cancelled" else 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
