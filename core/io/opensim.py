"""OpenSim motion (``.mot``) and marker (``.trc``) files: read and write.

``.mot`` (OpenSim ``Storage``, version 1): header lines ``name``, ``version=1``, ``nRows=N``,
``nColumns=M`` (the time column included), ``inDegrees=yes|no``, free lines, ``endheader``; then
one tab-separated line of column labels beginning with ``time`` and ``N`` lines of ``M`` numbers.

``.trc`` (``PathFileType 4 (X/Y/Z)``): line 2 the names ``DataRate CameraRate NumFrames
NumMarkers Units OrigDataRate OrigDataStartFrame OrigNumFrames``, line 3 their values, line 4
``Frame# Time`` and each marker's name (over its three columns), line 5 ``X1 Y1 Z1 X2 …``, a
blank line may follow, then per frame its number, time and ``3 x NumMarkers`` coordinates
(tab-separated; an empty or NaN field is a missing marker).

Kinematics of tracked bones (:func:`bone_kinematics_table`): per bone six coordinates in the
order OpenSim's gait models give a free pelvis — ``<bone>_tilt`` (about z), ``_list`` (x),
``_rotation`` (y), then ``_tx, _ty, _tz`` in metres — with ``R = Rz(tilt) Rx(list) Ry(rotation)``
(the body-fixed Z-X-Y sequence of the pelvis ``CustomJoint``). OpenSim's ground is y-up;
``T_ground_from_lab`` maps Talus's lab into it.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .atomic import atomic_write
from .errors import reads

__all__ = [
    "MarkerTable",
    "MotionTable",
    "bone_kinematics_table",
    "bone_markers",
    "kinematics_to_poses",
    "read_mot",
    "read_trc",
    "write_mot",
    "write_trc",
]


@dataclass(frozen=True)
class MotionTable:
    labels: tuple[str, ...]  # without "time"
    time: np.ndarray  # (n,)
    data: np.ndarray  # (n, len(labels))
    in_degrees: bool = True
    name: str = "talus"


@dataclass(frozen=True)
class MarkerTable:
    names: tuple[str, ...]
    xyz: np.ndarray  # (n_frames, n_markers, 3), NaN = missing
    rate: float
    units: str = "mm"
    frames: np.ndarray | None = None  # (n,) frame numbers
    time: np.ndarray | None = None


def _fmt(x: float) -> str:
    return "NaN" if math.isnan(x) else f"{x:.10g}"


def _labels_ok(labels, what: str) -> tuple[str, ...]:
    out = tuple(str(s) for s in labels)
    for s in out:
        if not s or any(c in s for c in "\t\r\n ") or s.lower() == "time":
            raise ValueError(f"{what}: expected names without blanks or line breaks, not 'time', got {s!r}")
    return out


# ------------------------------------------------------------------------------------ .mot
def write_mot(path: str | os.PathLike, table: MotionTable) -> None:
    """Write ``table`` as an OpenSim ``.mot`` file, atomically."""
    labels = _labels_ok(table.labels, "table.labels")
    t = np.asarray(table.time, dtype=float)
    D = np.asarray(table.data, dtype=float)
    if t.ndim != 1 or D.shape != (len(t), len(labels)) or not len(t):
        raise ValueError(f"table: expected time (n,) and data (n, {len(labels)}), got {t.shape}, {D.shape}")
    if not np.all(np.isfinite(t)):
        raise ValueError("table.time: expected finite times")
    name = str(table.name).strip() or "talus"
    if "\n" in name or "\r" in name:
        raise ValueError("table.name: expected one line")
    head = [name, "version=1", f"nRows={len(t)}", f"nColumns={len(labels) + 1}",
            f"inDegrees={'yes' if table.in_degrees else 'no'}", "endheader", "\t".join(("time", *labels))]
    rows = ["\t".join([_fmt(t[i]), *(_fmt(v) for v in D[i])]) for i in range(len(t))]
    atomic_write(path, "\n".join(head + rows) + "\n")


def read_mot(path: str | os.PathLike) -> MotionTable:
    """Read an OpenSim ``.mot`` / ``.sto`` (version 1) table."""
    return _read_mot(Path(path))


def _floats(path, no, parts, n) -> list[float]:
    if len(parts) != n:
        raise ValueError(f"{path}: line {no}: {len(parts)} values, expected {n}")
    try:
        return [float(p) for p in parts]
    except ValueError:
        raise ValueError(f"{path}: line {no}: expected numbers") from None


@reads("an OpenSim motion file (.mot: header, 'endheader', a label line starting with 'time', rows)")
def _read_mot(path: Path) -> MotionTable:
    lines = path.read_text(encoding="utf-8-sig").splitlines()
    try:
        end = next(i for i, ln in enumerate(lines) if ln.strip().lower() == "endheader")
    except StopIteration:
        raise ValueError(f"{path}: no 'endheader' line") from None
    meta = {}
    for ln in lines[1:end]:
        k, sep, v = ln.partition("=")
        if sep:
            meta[k.strip().lower()] = v.strip()
    in_deg = meta.get("indegrees", "yes").lower() != "no"
    body = [(i + 1, ln) for i, ln in enumerate(lines[end + 1 :], start=end + 1) if ln.strip()]
    if not body:
        raise ValueError(f"{path}: no column labels after 'endheader'")
    labels = body[0][1].split("\t") if "\t" in body[0][1] else body[0][1].split()
    labels = [s.strip() for s in labels]
    if not labels or labels[0].lower() != "time":
        raise ValueError(f"{path}: line {body[0][0]}: expected the labels to start with 'time'")
    rows = [_floats(path, no, ln.split(), len(labels)) for no, ln in body[1:]]
    if "nrows" in meta:
        try:
            n = int(meta["nrows"])
        except ValueError:
            raise ValueError(f"{path}: nRows={meta['nrows']!r} is not an integer") from None
        if n != len(rows):
            raise ValueError(f"{path}: nRows={n} but {len(rows)} data lines")
    if not rows:
        raise ValueError(f"{path}: no data lines")
    A = np.array(rows)
    if not np.all(np.isfinite(A[:, 0])):
        raise ValueError(f"{path}: non-finite time")
    return MotionTable(tuple(labels[1:]), A[:, 0], A[:, 1:], in_deg, lines[0].strip() if end > 0 else "")


def _zxy(R: np.ndarray) -> np.ndarray:
    """(tilt z, list x, rotation y) in degrees of ``R = Rz Rx Ry``; list in [-90, 90]."""
    x = np.arcsin(np.clip(R[..., 2, 1], -1, 1))
    z = np.arctan2(-R[..., 0, 1], R[..., 1, 1])
    y = np.arctan2(-R[..., 2, 0], R[..., 2, 2])
    return np.degrees(np.stack([z, x, y], -1))


def _rzxy(a: np.ndarray) -> np.ndarray:
    from .jointtrack import euler312_to_matrix

    z = np.zeros((*a.shape[:-1], 6))
    z[..., 3:] = a
    return euler312_to_matrix(z)[..., :3, :3]


def bone_kinematics_table(bones, poses, time, *, T_ground_from_lab=None, name: str = "talus") -> MotionTable:
    """Tracked poses ``(n, n_bones, 4, 4)`` (mm, lab) as an OpenSim coordinate table (see module)."""
    P = np.asarray(poses, dtype=float)
    names = _labels_ok(bones, "bones")
    if P.ndim != 4 or P.shape[1:] != (len(names), 4, 4):
        raise ValueError(f"poses: expected shape (n_frames, {len(names)}, 4, 4), got {P.shape}")
    G = np.eye(4) if T_ground_from_lab is None else np.asarray(T_ground_from_lab, dtype=float)
    Pg = G @ P
    cols, labels = [], []
    for b, n in enumerate(names):
        ang = _zxy(Pg[:, b, :3, :3])
        cols += [ang, Pg[:, b, :3, 3] / 1000.0]
        labels += [f"{n}_tilt", f"{n}_list", f"{n}_rotation", f"{n}_tx", f"{n}_ty", f"{n}_tz"]
    return MotionTable(tuple(labels), np.asarray(time, dtype=float), np.concatenate(cols, axis=1), True, name)


def kinematics_to_poses(table: MotionTable, bones, *, T_ground_from_lab=None) -> np.ndarray:
    """Inverse of :func:`bone_kinematics_table`: ``(n, n_bones, 4, 4)`` lab poses in mm."""
    idx = {s: i for i, s in enumerate(table.labels)}
    out = np.zeros((len(table.time), len(bones), 4, 4))
    for b, n in enumerate(bones):
        try:
            cols = [idx[f"{n}_{s}"] for s in ("tilt", "list", "rotation", "tx", "ty", "tz")]
        except KeyError as exc:
            raise ValueError(f"table: no column {exc.args[0]!r}") from None
        v = table.data[:, cols]
        ang = v[:, :3] if table.in_degrees else np.degrees(v[:, :3])
        out[:, b, :3, :3] = _rzxy(ang)
        out[:, b, :3, 3] = v[:, 3:] * 1000.0
        out[:, b, 3, 3] = 1.0
    G = np.eye(4) if T_ground_from_lab is None else np.asarray(T_ground_from_lab, dtype=float)
    return np.linalg.inv(G) @ out


# ------------------------------------------------------------------------------------ .trc
def bone_markers(poses, points) -> np.ndarray:
    """Virtual markers: ``points`` ``(n_points, 3)`` (bone frame, mm) carried by ``poses``
    ``(n, 4, 4)`` -> ``(n, n_points, 3)`` lab positions (NaN where the pose is NaN)."""
    P = np.asarray(poses, dtype=float)
    X = np.asarray(points, dtype=float)
    return np.einsum("nij,pj->npi", P[:, :3, :3], X) + P[:, None, :3, 3]


def write_trc(path: str | os.PathLike, table: MarkerTable) -> None:
    """Write ``table`` as a ``.trc`` file (``PathFileType 4``), atomically."""
    names = _labels_ok(table.names, "table.names")
    X = np.asarray(table.xyz, dtype=float)
    if X.ndim != 3 or X.shape[1:] != (len(names), 3) or not len(X):
        raise ValueError(f"table.xyz: expected shape (n_frames, {len(names)}, 3), got {X.shape}")
    rate = float(table.rate)
    if not rate > 0 or not math.isfinite(rate):
        raise ValueError(f"table.rate: expected a positive frame rate, got {table.rate!r}")
    if table.units not in ("mm", "m", "cm"):
        raise ValueError(f"table.units: expected 'mm', 'cm' or 'm', got {table.units!r}")
    n = len(X)
    frames = np.arange(1, n + 1) if table.frames is None else np.asarray(table.frames)
    time = (frames - frames[0]) / rate if table.time is None else np.asarray(table.time, dtype=float)
    p = Path(path)
    head = [
        f"PathFileType\t4\t(X/Y/Z)\t{p.name}",
        "DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits\tOrigDataRate\tOrigDataStartFrame\tOrigNumFrames",
        f"{rate:g}\t{rate:g}\t{n}\t{len(names)}\t{table.units}\t{rate:g}\t{int(frames[0])}\t{n}",
        "\t".join(["Frame#", "Time"] + [f"{m}\t\t" for m in names]).rstrip("\t"),
        "\t\t" + "\t".join(f"X{k + 1}\tY{k + 1}\tZ{k + 1}" for k in range(len(names))),
        "",
    ]
    rows = []
    for i in range(n):
        vals = ["" if math.isnan(v) else f"{v:.10g}" for v in X[i].ravel()]
        rows.append("\t".join([str(int(frames[i])), f"{time[i]:.10g}", *vals]))
    atomic_write(p, "\n".join(head + rows) + "\n")


def read_trc(path: str | os.PathLike) -> MarkerTable:
    """Read a ``.trc`` marker file; missing coordinates become NaN."""
    return _read_trc(Path(path))


@reads("an OpenSim/Motion Analysis .trc marker file (PathFileType 4, 5 header lines, then frames)")
def _read_trc(path: Path) -> MarkerTable:
    lines = path.read_text(encoding="utf-8-sig").splitlines()
    if len(lines) < 5 or not lines[0].startswith("PathFileType"):
        raise ValueError(f"{path}: line 1: expected 'PathFileType 4 (X/Y/Z) …' and 4 more header lines")
    keys = lines[1].split("\t")
    vals = lines[2].split("\t")
    if len(keys) != len(vals):
        raise ValueError(f"{path}: line 3: {len(vals)} values under {len(keys)} names")
    meta = dict(zip((k.strip() for k in keys), (v.strip() for v in vals), strict=True))
    try:
        rate = float(meta["DataRate"])
        nm = int(meta["NumMarkers"])
        nf = int(meta["NumFrames"])
    except (KeyError, ValueError):
        raise ValueError(f"{path}: line 3: expected DataRate, NumFrames and NumMarkers numbers") from None
    if not (rate > 0 and math.isfinite(rate)) or nm < 1 or nf < 0:
        raise ValueError(f"{path}: line 3: DataRate {rate}, NumMarkers {nm}, NumFrames {nf} out of range")
    names = [s.strip() for s in lines[3].split("\t")[2:] if s.strip()]
    if len(names) != nm:
        raise ValueError(f"{path}: line 4: {len(names)} marker names, expected NumMarkers={nm}")
    frames, times, xyz = [], [], []
    for no, ln in enumerate(lines[5:], start=6):
        if not ln.strip():
            continue
        parts = ln.split("\t")
        parts += [""] * (2 + 3 * nm - len(parts))
        if len(parts) > 2 + 3 * nm and any(p.strip() for p in parts[2 + 3 * nm :]):
            raise ValueError(f"{path}: line {no}: more than {2 + 3 * nm} values")
        try:
            fnum = float(parts[0])
            t = float(parts[1])
            v = [float(p) if p.strip() else math.nan for p in parts[2 : 2 + 3 * nm]]
        except ValueError:
            raise ValueError(f"{path}: line {no}: expected frame number, time and coordinates") from None
        if not (math.isfinite(fnum) and math.isfinite(t)) or any(math.isinf(x) for x in v):
            raise ValueError(f"{path}: line {no}: non-finite frame, time or coordinate")
        frames.append(int(fnum))
        times.append(t)
        xyz.append(v)
    if len(xyz) != nf:
        raise ValueError(f"{path}: NumFrames={nf} but {len(xyz)} frame lines")
    X = np.array(xyz, dtype=float).reshape(len(xyz), nm, 3)
    return MarkerTable(tuple(names), X, rate, meta.get("Units", "mm"), np.array(frames), np.array(times))
