"""``talus batch --smooth``: once a batch has run, each trial whose tasks are all complete has its
bones' poses smoothed over the trial (:func:`core.tracking.smoothing_trial.smooth_trial`, as
``talus track --smooth``) into ``results/reports/smoothing/<trial>.json``, after the trajectory
pass (whose flags the smoother weighs). A trial with a task not complete (failed, stopped,
cancelled) is not smoothed: the summary's entry says which tasks. The journal's poses stay the
results. The window's batch (:mod:`app.batch_panel`) does the same with *Tracking options*' *Smooth
the poses afterwards*, on the study it has open."""

from __future__ import annotations

import sys
from collections.abc import Sequence
from pathlib import Path

from ._shared import PROG

__all__ = ["smooth_lines", "smooth_messages", "smooth_trials"]


def smooth_trials(tasks: Sequence, records: Sequence[dict], *, threshold_hu: float = 200.0, study=None,
                  cancel=None) -> list[dict]:
    """Per (study, trial) of ``tasks`` (:class:`core.tracking.batch.BatchTask`) in order: ``study``,
    ``trial``, and either ``report`` (relative to the study), ``bones`` smoothed and ``skipped``
    (bone -> why), or ``not_smoothed`` (the tasks not complete, or the error). ``records``: the
    summary's ``task_records`` (``key``, ``status``). ``study``: a study already open for writing
    (the window's), used for its own folder's tasks; ``cancel()`` True stops before the next trial
    (those left out: ``not_smoothed`` "cancelled")."""
    from core.study import Study
    from core.tracking.smoothing_trial import REPORT_KIND, smooth_trial

    status = {r.get("key"): r.get("status") for r in records}
    groups: dict[tuple[str, str], list] = {}
    for t in tasks:
        groups.setdefault((str(t.study), t.trial), []).append(t)
    out = []
    for (folder, trial), ts in groups.items():
        head = {"study": folder, "trial": trial}
        missing = [t.key for t in ts if status.get(t.key) != "complete"]
        if cancel is not None and cancel():
            out.append(dict(head, not_smoothed="cancelled"))
            continue
        if missing:
            named = ", ".join(missing[:3]) + (" ..." if len(missing) > 3 else "")
            out.append(dict(head, not_smoothed=f"{len(missing)} of {len(ts)} tasks not complete ({named})"))
            continue
        bones = list(dict.fromkeys(b for t in ts for b in t.bones))
        try:
            if study is not None and Path(study.folder).resolve() == Path(folder).resolve():
                rep = smooth_trial(study, trial, bones, threshold_hu=threshold_hu)
            else:
                with Study.open(Path(folder), mode="w") as st:
                    rep = smooth_trial(st, trial, bones, threshold_hu=threshold_hu)
        except Exception as exc:  # reported; the tracked poses are in the journal all the same
            out.append(dict(head, not_smoothed=f"{type(exc).__name__}: {exc}"))
            continue
        out.append(dict(head, report=f"results/reports/{REPORT_KIND}/{trial}.json",
                        bones=sorted(rep["bones"]), skipped=rep["skipped"]))
    return out


def smooth_messages(entries: Sequence[dict], *, file=None) -> list[str]:
    """:func:`smooth_lines` printed to ``file`` (stderr by default) with the program's name; returns them."""
    lines = smooth_lines(entries)
    for line in lines:
        print(f"{PROG} batch: {line}", file=file or sys.stderr)
    return lines


def smooth_lines(entries: Sequence[dict]) -> list[str]:
    """One line per trial of :func:`smooth_trials`' entries (and one per bone skipped)."""
    lines = []
    for e in entries:
        where = f"{Path(e['study']).name}/{e['trial']}"
        if "not_smoothed" in e:
            lines.append(f"{where}: not smoothed: {e['not_smoothed']}")
            continue
        lines += [f"{where}: {b} not smoothed: {why}" for b, why in e["skipped"].items()]
        if e["bones"]:
            lines.append(f"{where}: smoothed poses of {', '.join(e['bones'])} in {e['report']}")
    return lines
