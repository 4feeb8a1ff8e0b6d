"""The command line and JSON set-up the tracking studies share (``python -m core.studies.tracking.<study>``).

A study's ``main`` builds its parser with :func:`parser` (``python -m <module>``, described by the
first line of its docs) and the options every study of a simulated trial takes —
:func:`add_scene` (``--pixels``, ``--voxel``, ``--n-frames``, ``--frames``, ``--seeds``, ``--sets``),
:func:`add_machine_name`, :func:`add_output` (``--machine-name``, ``--table``, ``--out``) — reads its
comma lists with :func:`names`, :func:`ints` and :func:`floats`, hands :func:`checkpoint` to its
``run`` and ends with :func:`finish`. A run's JSON starts with :func:`header` and
:func:`frame_done` writes it after each frame:

* each checkpoint writes the results so far to ``--out`` atomically, indented by one, with
  ``machine_name`` (``--machine-name``) set, so a run stopped part-way keeps what it measured;
* :func:`finish` sets ``machine_name`` again, prints the study's table to stderr (``--table``) and
  the results as JSON on stdout, written to ``--out`` as well (:func:`core.io.atomic.print_json`).
"""

from __future__ import annotations

import argparse
import platform
import sys
import time
from collections.abc import Callable, Sequence

__all__ = ["CPU_MACHINE", "add_machine_name", "add_output", "add_scene", "checkpoint", "finish", "floats",
           "frame_done", "header", "ints", "names", "parser", "stored_parser", "write_stamped"]

#: ``--bones``' help (and alike options': bone indices of the scene).
BONES_HELP = "bone indices (default all)"


def parser(module: str, doc: str | None) -> argparse.ArgumentParser:
    """``python -m <module>``'s parser, described by the first line of ``doc`` (the module's docs)."""
    return argparse.ArgumentParser(prog=f"python -m {module}", description=(doc or "").split("\n")[0])


def add_scene(p: argparse.ArgumentParser, *, frames: str, sets: str, pixels: int = 256, voxel: float = 1.0,
              n_frames: int = 20, seeds: int = 2) -> None:
    """The simulated trial's options: ``--pixels``, ``--voxel`` (mm), ``--n-frames``, ``--frames``
    and ``--sets`` (comma lists), ``--seeds`` (noise draws a frame)."""
    p.add_argument("--pixels", type=int, default=pixels)
    p.add_argument("--voxel", type=float, default=voxel)
    p.add_argument("--n-frames", type=int, default=n_frames,
                   help="the trial's length (its phase scales with it)")
    p.add_argument("--frames", default=frames)
    p.add_argument("--seeds", type=int, default=seeds)
    p.add_argument("--sets", default=sets)


#: ``--machine-name``'s default for the studies of stored runs (:func:`stored_parser`): they judge on the CPU.
CPU_MACHINE = "this 2-core x86_64 machine, shared"


def stored_parser(module: str, doc: str | None, what: str = "the results") -> argparse.ArgumentParser:
    """The parser of a study of stored runs (trajectory_gaps, trajectory_pairs, trajectory_silent,
    trajectory_ends): :func:`parser` (``module``: its name under ``core.studies.tracking``) with ``--out``
    ("write ``what`` as JSON here") and ``--machine-name`` (default :data:`CPU_MACHINE`); the study adds
    its own options after them and writes its JSON with :func:`write_stamped`."""
    p = parser(f"core.studies.tracking.{module}", doc)
    p.add_argument("--out", default=None, help=f"write {what} as JSON here")
    p.add_argument("--machine-name", default=CPU_MACHINE)
    return p


def add_machine_name(p: argparse.ArgumentParser) -> None:
    """``--machine-name``: written into the JSON as ``machine_name``."""
    p.add_argument("--machine-name", default=None, help="a name for the machine, written into the JSON")


def add_output(p: argparse.ArgumentParser, *, machine_name: bool = True, table: bool = False) -> None:
    """The last options: ``--machine-name`` (:func:`add_machine_name`; ``machine_name`` False: none,
    or added before), ``--table`` (``table``: the summary table to stderr at the end), ``--out``."""
    if machine_name:
        add_machine_name(p)
    if table:
        p.add_argument("--table", action="store_true", help="print the summary table to stderr at the end")
    p.add_argument("--out", default=None, help="also write the JSON here")


def names(text: str) -> list[str]:
    """A comma list's items (empty ones dropped)."""
    return [x for x in text.split(",") if x]


def ints(text: str) -> list[int]:
    """A comma list of whole numbers (empty items dropped)."""
    return [int(x) for x in names(text)]


def floats(text: str) -> list[float]:
    """A comma list of numbers (empty items dropped)."""
    return [float(x) for x in names(text)]


def checkpoint(a: argparse.Namespace) -> Callable[[dict], None]:
    """The run's checkpoint (:func:`core.io.atomic.json_checkpoint`): the results so far to
    ``a.out``, indented by one, with ``machine_name`` where ``a`` has one."""
    from core.io.atomic import json_checkpoint

    return json_checkpoint(a.out, indent=1, machine_name=getattr(a, "machine_name", None))


def header(study: str, **fields) -> dict:
    """A run's JSON as it starts: ``study`` (its module), ``machine`` (the architecture), ``fields``."""
    return {"study": study, "machine": platform.machine(), **fields}


def frame_done(out: dict, f: int, t0: float, save: Callable[[dict], None] | None,
               done: Sequence[int] | None = None) -> None:
    """After frame ``f``: ``out``'s ``frames_done`` (``done``, where given) and ``total_s`` (since
    ``t0``, :func:`time.perf_counter`), a progress line on stdout, and ``save(out)`` (a checkpoint)."""
    if done is not None:
        out["frames_done"] = list(done)
    out["total_s"] = time.perf_counter() - t0
    print(f"frame {f} done {out['total_s']:.0f}s", flush=True)
    if save:
        save(out)


def finish(res: dict, a: argparse.Namespace, table: Callable[[dict], list[str]] | None = None) -> int:
    """The end of ``main``: ``res``' ``machine_name`` (where ``a`` has one), the ``table`` lines on
    stderr (where ``a.table``), ``res`` as JSON on stdout and to ``a.out``; returns 0."""
    from core.io.atomic import print_json

    if getattr(a, "machine_name", None):
        res["machine_name"] = a.machine_name
    if table is not None and getattr(a, "table", False):
        print("\n".join(table(res)), file=sys.stderr)
    print_json(res, a.out)
    return 0


def write_stamped(path, module: str, argv: Sequence[str] | None, machine: str, res: dict) -> None:
    """Write ``res`` to ``path`` (indented by one) after the run's stamp: ``study`` (``module``),
    ``command`` (``python -m <module>`` and the arguments, ``argv`` or the process's), ``commit`` (the
    checkout's short HEAD), ``machine`` and ``cpu_s`` (the process's CPU time so far) — the stored-run
    studies' JSON (:func:`stored_parser`'s)."""
    import json
    import subprocess
    from pathlib import Path

    head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                          cwd=Path(__file__).resolve().parents[3]).stdout.strip()
    args = sys.argv[1:] if argv is None else argv
    Path(path).write_text(json.dumps({"study": module, "command": f"python -m {module} " + " ".join(args),
                                      "commit": head, "machine": machine,
                                      "cpu_s": round(time.process_time(), 1), **res}, indent=1) + "\n")
