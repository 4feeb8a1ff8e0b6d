"""Is this folder a complete demo study? The one check behind ``talus demo`` (which reuses a demo
made with the same options) and the welcome page's "Open the demo" (which writes it only once),
and :func:`write_demo`, the one place both write it (the demo is synthetic by design: the only
user-facing path that imports :mod:`core.synthetic`).

A complete demo is what :func:`core.synthetic.demo.make_demo_study` leaves when it finishes: a
``summary.json`` of format ``talus-synthetic-study`` with status ``complete``, the study manifest
it names (``study.json``) and, unless told otherwise, the calibration session it names.
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping
from pathlib import Path

__all__ = ["DEMO_FORMAT", "complete_demo", "write_demo"]

#: The ``format`` of a demo study's ``summary.json``.
DEMO_FORMAT = "talus-synthetic-study"


def complete_demo(folder: str | os.PathLike, *, calibration_session: bool = True,
                  options: Mapping[str, object] | None = None) -> dict | None:
    """The ``summary.json`` of the complete demo study in ``folder``, or None when there is none.

    Parameters
    ----------
    folder : path
        The demo's output folder.
    calibration_session : bool
        Also require the calibration session the summary names (its ``session.json``): a demo
        made before demos had one, or whose session was removed, is then not complete. False
        asks only for the study (demos written with ``calibration_session=False``).
    options : mapping, optional
        Summary keys and the values they must have (e.g. ``{"n_frames": 10, "pixels": 512}``);
        a value of None accepts any.
    """
    out = Path(folder)
    try:
        summary = json.loads((out / "summary.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    if not isinstance(summary, dict):
        return None
    if summary.get("format") != DEMO_FORMAT or summary.get("status") != "complete":
        return None
    if not (out / str(summary.get("study") or "study.json")).is_file():
        return None  # no study manifest (a demo of an older Talus, or it was removed)
    if calibration_session:
        session = summary.get("calibration_session")
        if not session or not (out / str(session) / "session.json").is_file():
            return None  # made before demos had a calibration session, or it is gone
    for key, value in (options or {}).items():
        if value is not None and summary.get(key) != value:
            return None
    return summary


def write_demo(folder: str | os.PathLike, *, progress=None, cancel=None, **options) -> dict:
    """Write the built-in synthetic demo study into ``folder``
    (:func:`core.synthetic.demo.make_demo_study` with ``options``; those left out take its
    defaults) and return its summary. ``progress(done, total, *stage)`` and ``cancel()`` as there.

    Raises
    ------
    CliError
        The generator cannot be imported (the missing module named).
    """
    from .commands._shared import load

    make_demo_study = load("core.synthetic.demo:make_demo_study", needed_for="the demo study")
    return make_demo_study(folder, **options, progress=progress, cancel=cancel)
