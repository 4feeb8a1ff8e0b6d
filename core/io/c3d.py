"""C3D files of tracked bones (read/write through ezc3d, the ``interop`` extra).

Written: ``POINT`` data — per bone its origin ``<bone>_O`` and three axis points ``<bone>_X``,
``_Y``, ``_Z`` 10 mm along its axes (what Visual3D and other gait tools build segments from),
``NaN`` where the bone has no pose — and the C3D ``ROTATION`` section (ezc3d's ``rotations``:
one 4x4 matrix per bone and frame, ``ROTATION:LABELS`` = bone names, ``ROTATION:RATIO`` 1),
which holds ``T_lab_from_bone`` (mm) directly. Units mm, ``POINT:RATE`` the frame rate.

Read: the rotations when the file has them, else nothing is invented — the points are returned
as they are. ezc3d runs in a child process for reading (it crashed the process with a
segmentation fault on damaged files while fuzzing), and for writing when SimpleITK was imported
before it (both are SWIG modules; in that order ezc3d's vectors match none of its overloads).
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .atomic import atomic_path
from .errors import FileError, reads

__all__ = ["AXIS_MM", "C3DBones", "read_c3d", "write_c3d"]

AXIS_MM = 10.0


@dataclass(frozen=True)
class C3DBones:
    bones: tuple[str, ...]  # ROTATION:LABELS
    poses: np.ndarray  # (n_frames, n_bones, 4, 4), NaN = no pose
    rate: float
    point_labels: tuple[str, ...]
    points: np.ndarray  # (n_frames, n_points, 3), NaN = missing
    units: str


def _ezc3d():
    try:
        import ezc3d
    except ImportError:  # pragma: no cover - depends on the installation
        raise ImportError("C3D files need ezc3d: pip install 'talus-biplane[interop]'") from None
    return ezc3d


def _clashes() -> bool:
    """True when ezc3d is (or would be) imported after SimpleITK in this process: both are SWIG modules
    and, in that order, ezc3d's own vectors match none of its overloads (TypeError on write, a
    "not standard" file on read). Then the C3D work runs in a fresh interpreter."""
    mods = list(sys.modules)  # in import order
    if "SimpleITK" not in mods:
        return False
    return "ezc3d" not in mods or mods.index("ezc3d") > mods.index("SimpleITK")


def _in_subprocess(code: str, *args: str, **arrays) -> dict:
    """Run ``code`` in a fresh interpreter (argv: a scratch folder holding ``in.npz``, then
    ``args``); returns the ``out.npz`` it wrote. A failure or a crash is a ``ValueError``."""
    root = Path(__file__).resolve().parents[2]
    with tempfile.TemporaryDirectory(prefix="talus-c3d-") as d:
        np.savez(Path(d) / "in.npz", **arrays)
        env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(root), os.environ.get("PYTHONPATH", "")])}
        r = subprocess.run([sys.executable, "-c", code, d, *args], env=env, capture_output=True, text=True)
        if r.returncode < 0:
            raise ValueError(f"ezc3d crashed on it (signal {-r.returncode})")
        if r.returncode:
            last = (r.stderr.strip().splitlines() or ["(no message)"])[-1]
            raise ValueError(last.split(": ", 1)[-1] if last.startswith(("OSError", "ValueError",
                                                                          "RuntimeError")) else last)
        out = Path(d) / "out.npz"
        return dict(np.load(out, allow_pickle=False)) if out.exists() else {}


def write_c3d(path: str | os.PathLike, bones, poses, *, rate: float) -> None:
    """Write ``poses`` ``(n_frames, n_bones, 4, 4)`` (``T_lab_from_bone``, mm) of ``bones``."""
    names = tuple(str(b) for b in bones)
    P = np.asarray(poses, dtype=float)
    if P.ndim != 4 or P.shape[1:] != (len(names), 4, 4) or not len(P):
        raise ValueError(f"poses: expected shape (n_frames, {len(names)}, 4, 4), got {P.shape}")
    if not names or len(set(names)) != len(names) or any(not n or len(n) > 24 for n in names):
        raise ValueError(f"bones: expected distinct names of 1-24 characters, got {names}")
    if not (float(rate) > 0 and np.isfinite(rate)):
        raise ValueError(f"rate: expected a positive frame rate, got {rate!r}")
    if _clashes():
        _in_subprocess(
            "import sys, numpy as np; from core.io.c3d import write_c3d;"
            " a = np.load(sys.argv[1] + '/in.npz');"
            " write_c3d(str(a['path']), [str(b) for b in a['bones']], a['poses'], rate=float(a['rate']))",
            path=np.array(str(Path(path).absolute())), bones=np.array(names), poses=P, rate=np.array(rate))
        return
    ezc3d = _ezc3d()
    n, nb = P.shape[:2]
    offsets = np.array([[0, 0, 0], [AXIS_MM, 0, 0], [0, AXIS_MM, 0], [0, 0, AXIS_MM]], dtype=float)
    pts = np.einsum("fbij,pj->fbpi", P[..., :3, :3], offsets) + P[:, :, None, :3, 3]  # (n, nb, 4, 3)
    labels = [f"{b}_{s}" for b in names for s in "OXYZ"]
    data = np.ones((4, nb * 4, n))
    data[:3] = pts.reshape(n, nb * 4, 3).transpose(2, 1, 0)
    c = ezc3d.c3d()
    c["parameters"]["POINT"]["RATE"]["value"] = [float(rate)]
    c["parameters"]["POINT"]["UNITS"]["value"] = ["mm"]
    c["parameters"]["POINT"]["LABELS"]["value"] = tuple(labels)
    c["data"]["points"] = data
    c["data"]["rotations"] = np.ascontiguousarray(P.transpose(2, 3, 1, 0))
    c.add_parameter("ROTATION", "LABELS", list(names))
    with atomic_path(path) as tmp:
        out = Path(tmp)
        if out.suffix.lower() != ".c3d":  # ezc3d writes the path as given
            out = out.with_suffix(out.suffix + ".c3d")
        c.write(str(out))
        if out != Path(tmp):
            os.replace(out, tmp)


def read_c3d(path: str | os.PathLike) -> C3DBones:
    """Read bones' poses (the ``ROTATION`` section) and points of a C3D file."""
    return _read(Path(path))


@reads("a C3D file")
def _read(path: Path) -> C3DBones:
    if not path.is_file():
        raise FileError(f"{path}: no such file", path=path)
    # ezc3d crashes the process (segmentation fault) on some damaged files: read in a child, which
    # runs _c3d_read.py by its path (numpy and ezc3d only, not the core.io package)
    script = Path(__file__).with_name("_c3d_read.py")
    a = _in_subprocess(f"import runpy; runpy.run_path({str(script)!r}, run_name='__main__')",
                       str(path.absolute()), dummy=np.zeros(0))
    return C3DBones(tuple(str(b) for b in a["bones"]), a["poses"], float(a["rate"]),
                    tuple(str(b) for b in a["point_labels"]), a["points"], str(a["units"]))
