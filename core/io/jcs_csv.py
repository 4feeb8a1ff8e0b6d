"""Joint-coordinate-system (Grood–Suntay) angle CSV: write and read.

One row per frame: ``frame`` (the trial's frame number), ``time_s``, then per joint
``<joint>_e1_deg, <joint>_e2_deg, <joint>_e3_deg`` (about e1 fixed in the proximal bone, the
floating axis, e3 fixed in the distal bone) and ``<joint>_e1_mm, _e2_mm, _e3_mm`` (the JCS
translations); empty cells for frames without both poses. The angles come from
:func:`core.tracking.jcs.joint_series` (the intrinsic e1-e2-e3 Euler sequence of the distal
anatomical frame relative to the proximal one). A first comment line ``# jcs <joint>: <proximal>
-> <distal>, e1 = <axis>, e3 = <axis>`` per joint records which axes were used.
"""

from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .atomic import atomic_write
from .errors import reads

__all__ = ["JCSTable", "jcs_table", "read_jcs_csv", "write_jcs_csv"]

_SUFFIX = ("e1_deg", "e2_deg", "e3_deg", "e1_mm", "e2_mm", "e3_mm")


@dataclass(frozen=True)
class JCSTable:
    joints: tuple[str, ...]
    frames: np.ndarray  # (n,)
    time: np.ndarray  # (n,) s
    values: np.ndarray  # (n, n_joints, 6): 3 angles (deg), 3 translations (mm)
    notes: tuple[str, ...] = ()


def jcs_table(poses, joints, *, frames, rate: float, anatomical=None) -> JCSTable:
    """JCS angles of ``joints`` (:class:`core.tracking.jcs.Joint`) from ``poses`` (bone ->
    ``(n, 4, 4)`` ``T_lab_from_bone``) and optional ``anatomical`` frames."""
    from ..tracking.jcs import joint_series

    fr = np.asarray(frames)
    vals = np.zeros((len(fr), len(joints), 6))
    notes = []
    for k, j in enumerate(joints):
        s = joint_series(poses, j, anatomical)
        vals[:, k, :3], vals[:, k, 3:] = s["angles_deg"], s["translations_mm"]
        notes.append(f"jcs {j.name}: {j.proximal} -> {j.distal}, e1 = {j.e1_axis}, e3 = {j.e3_axis}")
    return JCSTable(tuple(j.name for j in joints), fr, (fr - fr[0]) / float(rate), vals, tuple(notes))


def write_jcs_csv(path: str | os.PathLike, table: JCSTable) -> None:
    """Write ``table`` atomically (see the module docs)."""
    V = np.asarray(table.values, dtype=float)
    n = len(table.frames)
    if V.shape != (n, len(table.joints), 6) or len(table.time) != n:
        raise ValueError(f"table: expected values of shape ({n}, {len(table.joints)}, 6), got {V.shape}")
    for j in table.joints:
        if not j or "," in j or "\n" in j or '"' in j:
            raise ValueError(f"table.joints: expected names without commas, quotes or line breaks, got {j!r}")
    lines = [f"# {note}" for note in table.notes if "\n" not in note]
    lines.append(",".join(["frame", "time_s"] + [f"{j}_{s}" for j in table.joints for s in _SUFFIX]))
    for i in range(n):
        cells = [str(int(table.frames[i])), f"{float(table.time[i]):.10g}"]
        cells += ["" if math.isnan(v) else f"{v:.10g}" for v in V[i].ravel()]
        lines.append(",".join(cells))
    atomic_write(path, "\n".join(lines) + "\n")


def read_jcs_csv(path: str | os.PathLike) -> JCSTable:
    """Read a JCS angle CSV written by :func:`write_jcs_csv`."""
    return _read(Path(path))


@reads("a JCS angle CSV (frame, time_s, then <joint>_e1_deg ... <joint>_e3_mm per joint)")
def _read(path: Path) -> JCSTable:
    lines = path.read_text(encoding="utf-8-sig").splitlines()
    notes = tuple(ln[1:].strip() for ln in lines if ln.startswith("#"))
    rows = [(no, ln) for no, ln in enumerate(lines, start=1) if ln.strip() and not ln.startswith("#")]
    if not rows:
        raise ValueError(f"{path}: no header line")
    no, head = rows[0]
    cols = head.split(",")
    if cols[:2] != ["frame", "time_s"] or (len(cols) - 2) % 6 or len(cols) < 8:
        raise ValueError(f"{path}: line {no}: expected 'frame,time_s' and 6 columns per joint")
    joints = []
    for k in range((len(cols) - 2) // 6):
        block = cols[2 + 6 * k : 8 + 6 * k]
        m = re.fullmatch(r"(.+)_e1_deg", block[0])
        if not m or block != [f"{m[1]}_{s}" for s in _SUFFIX]:
            raise ValueError(f"{path}: line {no}: columns {3 + 6 * k}-{8 + 6 * k} are not one joint's "
                             f"<joint>_e1_deg ... <joint>_e3_mm")
        joints.append(m[1])
    frames, times, vals = [], [], []
    for no, ln in rows[1:]:
        cells = ln.split(",")
        if len(cells) != len(cols):
            raise ValueError(f"{path}: line {no}: {len(cells)} cells, expected {len(cols)}")
        try:
            f = float(cells[0])
            t = float(cells[1])
            v = [float(c) if c.strip() else math.nan for c in cells[2:]]
        except ValueError:
            raise ValueError(f"{path}: line {no}: expected numbers (or empty cells)") from None
        if not f.is_integer() or not math.isfinite(t) or any(math.isinf(x) for x in v):
            raise ValueError(f"{path}: line {no}: frame must be an integer, time and values finite")
        frames.append(int(f))
        times.append(t)
        vals.append(v)
    V = np.array(vals, dtype=float).reshape(len(vals), len(joints), 6)
    return JCSTable(tuple(joints), np.array(frames, dtype=int), np.array(times), V, notes)
