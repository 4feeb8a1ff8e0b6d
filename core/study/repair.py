"""Salvage of damaged pose journals over a whole study (``talus study repair``).

A journal line whose checksum fails in the middle of a file is corruption, not a crash
artefact, and :func:`core.study.results.read_journal` refuses the journal rather than read
silently wrong data. :func:`repair_study` runs :func:`core.study.results.salvage_journal` over
every journal of a study (``results/<trial>/poses/<bone>.jsonl``): each damaged journal keeps
every record whose checksum holds, its original is set aside as ``<bone>.jsonl.damaged-<time>``
beside it, and the report lists the dropped lines with their line numbers and reasons.
"""

from __future__ import annotations

from .errors import LockedError, StudyError
from .results import salvage_journal

__all__ = ["repair_study"]


def repair_study(study, *, dry_run: bool = False) -> dict:  # study: a Study (study.py imports this module)
    """Salvage every pose journal of ``study`` (open for writing unless ``dry_run``).

    Returns a JSON-ready dict: ``study`` (folder), ``dry_run``, ``journals`` (one
    :func:`~core.study.results.salvage_journal` report per journal file, with ``trial`` and
    ``bone``), ``damaged`` (journals with dropped lines), ``dropped_lines`` (their total) and
    ``skipped`` (journals left alone: not regular files, or damaged ones whose lock another
    writer holds or whose trial or bone the manifest no longer has, with the reason). A damaged
    journal is locked (:meth:`~core.study.Study.lock_journal`) before it is rewritten.
    """
    if not dry_run:
        study._require_write()
    root = study.folder / "results"
    out = {"study": str(study.folder), "dry_run": bool(dry_run), "journals": [], "damaged": 0,
           "dropped_lines": 0, "skipped": []}
    if not root.is_dir() or root.is_symlink():
        return out
    for path in sorted(root.glob("*/poses/*.jsonl")):
        if path.is_symlink() or not path.is_file() or path.name.startswith("."):
            out["skipped"].append(str(path))
            continue
        trial, bone = path.parent.parent.name, path.stem
        rep = salvage_journal(path, dry_run=True)
        if rep["dropped"] and not dry_run:
            try:  # no other writer may append while the journal is rewritten
                study.lock_journal(trial, bone)
            except (LockedError, StudyError) as exc:
                out["skipped"].append(f"{path} ({exc})")
                continue
            rep = salvage_journal(path)
        rep = {"trial": trial, "bone": bone, **rep}
        out["journals"].append(rep)
        if rep["dropped"]:
            out["damaged"] += 1
            out["dropped_lines"] += len(rep["dropped"])
    return out
