"""ITK transform files (``.tfm``) as 3D Slicer and SlicerAutoscoperM read and write them.

Format (ITK ``TransformFileReader``, text ``#Insight Transform File V1.0``): one or more blocks
``#Transform n`` / ``Transform: <class>`` / ``Parameters: …`` / ``FixedParameters: …``. The linear
classes read here (``AffineTransform_{double,float}_3_3``, ``MatrixOffsetTransformBase_…_3_3``)
hold 12 parameters ``a11 a12 a13 a21 … a33 tx ty tz`` and the centre ``c`` as fixed parameters;
a point maps as ``y = A (x - c) + c + t``. ``Euler3DTransform``, ``VersorRigid3DTransform`` and
``TranslationTransform`` are read as well; several blocks in one file compose (ITK applies the
last block first — a composite transform's ``TransformPoint`` order).

Conventions (Slicer's developer guide, "Transforms: Transform files"): files are in LPS and store
the *resampling* transform (fixed -> moving, Slicer's "from parent"); Slicer's scene is RAS and
shows the *modelling* transform ("to parent"). So a pose ``T_parent_from_child`` in RAS is
written as ``F @ inv(T) @ F`` with ``F = diag(-1, -1, 1)``; :func:`read_slicer_tfm` returns
``T_parent_from_child`` in RAS and :func:`read_itk_tfm` the file's own matrix.

SlicerAutoscoperM names its per-volume files ``<volume>.tfm`` (spacing and origin),
``<volume>_t.tfm``, ``<volume>_scale.tfm`` and ``<volume>-PVOL2AUT.tfm`` / ``-DICOM2AUT.tfm``
(``AutoscoperM/AutoscoperM.py`` lines 770-772, 1090-1102 of BrownBiomechanics/SlicerAutoscoperM);
its PVOL2AUT transform is the 180° turn about x with a y offset of the volume's size (lines
1291-1304), the same frame as :mod:`core.io.autoscoper_pose` derives from Autoscoper's source.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np

from .atomic import atomic_write
from .errors import reads

__all__ = ["LPS_RAS", "read_itk_tfm", "read_slicer_tfm", "write_itk_tfm", "write_slicer_tfm"]

LPS_RAS = np.diag([-1.0, -1.0, 1.0, 1.0])
LPS_RAS.setflags(write=False)
_LINEAR = ("AffineTransform_", "MatrixOffsetTransformBase_")


def _euler_zxy(ax: float, ay: float, az: float) -> np.ndarray:
    """ITK Euler3DTransform's default (ZXY) rotation ``Rz @ Rx @ Ry``."""
    cx, sx = math.cos(ax), math.sin(ax)
    cy, sy = math.cos(ay), math.sin(ay)
    cz, sz = math.cos(az), math.sin(az)
    Rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    Ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    Rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return Rz @ Rx @ Ry


def _block_matrix(path, cls: str, p: list[float], fixed: list[float]) -> np.ndarray:
    T = np.eye(4)
    c = np.zeros(3)
    if cls.startswith(_LINEAR) and cls.endswith("_3_3"):
        if len(p) != 12:
            raise ValueError(f"{path}: {cls}: expected 12 parameters, got {len(p)}")
        A, t = np.array(p[:9]).reshape(3, 3), np.array(p[9:])
        if fixed:
            c = np.array(fixed[:3]) if len(fixed) >= 3 else None
    elif cls.startswith("Euler3DTransform_"):
        if len(p) != 6:
            raise ValueError(f"{path}: {cls}: expected 6 parameters, got {len(p)}")
        A, t = _euler_zxy(*p[:3]), np.array(p[3:])
        if len(fixed) > 3 and fixed[3] != 0:
            Rx, Ry, Rz = (_euler_zxy(p[0], 0, 0), _euler_zxy(0, p[1], 0), _euler_zxy(0, 0, p[2]))
            A = Rz @ Ry @ Rx  # ComputeZYX flag set
        c = np.array(fixed[:3]) if len(fixed) >= 3 else np.zeros(3)
    elif cls.startswith("VersorRigid3DTransform_"):
        if len(p) != 6:
            raise ValueError(f"{path}: {cls}: expected 6 parameters, got {len(p)}")
        v = np.array(p[:3])
        n2 = float(v @ v)
        if n2 > 1:
            raise ValueError(f"{path}: {cls}: versor norm {math.sqrt(n2):.6g} > 1")
        from scipy.spatial.transform import Rotation

        A = Rotation.from_quat([*v, math.sqrt(1 - n2)]).as_matrix()
        t = np.array(p[3:])
        c = np.array(fixed[:3]) if len(fixed) >= 3 else np.zeros(3)
    elif cls.startswith("TranslationTransform_"):
        if len(p) != 3:
            raise ValueError(f"{path}: {cls}: expected 3 parameters, got {len(p)}")
        A, t = np.eye(3), np.array(p)
    else:
        raise ValueError(f"{path}: transform class {cls!r} is not a 3-D linear transform read here")
    if c is None:
        raise ValueError(f"{path}: {cls}: expected 3 fixed parameters (the centre), got {len(fixed)}")
    if np.linalg.matrix_rank(A) < 3:
        raise ValueError(f"{path}: {cls}: the matrix is singular")
    T[:3, :3] = A
    T[:3, 3] = t + c - A @ c
    return T


def read_itk_tfm(path: str | os.PathLike) -> np.ndarray:
    """The 4x4 matrix of an ITK ``.tfm`` file as stored (LPS, resampling direction)."""
    return _read(Path(path))


@reads("an ITK transform file (#Insight Transform File V1.0 with linear 3-D transforms)")
def _read(path: Path) -> np.ndarray:
    text = path.read_text(encoding="utf-8-sig")
    lines = [ln.strip() for ln in text.splitlines()]
    if not lines or not lines[0].startswith("#Insight Transform File"):
        raise ValueError(f"{path}: line 1: expected '#Insight Transform File V1.0'")
    blocks: list[dict] = []
    for no, ln in enumerate(lines, start=1):
        if not ln or ln.startswith("#"):
            continue
        key, sep, val = ln.partition(":")
        if not sep:
            raise ValueError(f"{path}: line {no}: expected 'Key: value', got {ln[:40]!r}")
        key = key.strip()
        if key == "Transform":
            blocks.append({"class": val.strip(), "line": no})
        elif key in ("Parameters", "FixedParameters"):
            if not blocks:
                raise ValueError(f"{path}: line {no}: {key} before any 'Transform:' line")
            try:
                nums = [float(x) for x in val.split()]
            except ValueError:
                raise ValueError(f"{path}: line {no}: {key}: expected numbers") from None
            if not all(math.isfinite(x) for x in nums):
                raise ValueError(f"{path}: line {no}: {key}: non-finite value")
            blocks[-1][key] = nums
        else:
            raise ValueError(f"{path}: line {no}: unknown key {key!r}")
    blocks = [b for b in blocks if not b["class"].startswith("CompositeTransform_")]
    if not blocks:
        raise ValueError(f"{path}: no 'Transform:' block")
    T = np.eye(4)
    for b in blocks:
        if "Parameters" not in b:
            raise ValueError(f"{path}: line {b['line']}: transform without 'Parameters:'")
        T = T @ _block_matrix(path, b["class"], b["Parameters"], b.get("FixedParameters", []))
    return T


def write_itk_tfm(path: str | os.PathLike, T) -> None:
    """Write ``T`` (4x4, last row 0 0 0 1) as one ``AffineTransform_double_3_3``, atomically."""
    T = np.asarray(T, dtype=float)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)) or not np.allclose(T[3], [0, 0, 0, 1]):
        raise ValueError(f"T: expected a finite 4x4 affine matrix (last row 0 0 0 1), got {T.shape}")
    if abs(np.linalg.det(T[:3, :3])) < 1e-12:
        raise ValueError("T: singular matrix")
    params = [*T[:3, :3].ravel(), *T[:3, 3]]
    text = (
        "#Insight Transform File V1.0\n#Transform 0\nTransform: AffineTransform_double_3_3\n"
        f"Parameters: {' '.join(repr(float(x)) for x in params)}\nFixedParameters: 0 0 0\n"
    )
    atomic_write(path, text)


def read_slicer_tfm(path: str | os.PathLike) -> np.ndarray:
    """``T_parent_from_child`` in RAS (Slicer's "to parent" matrix) of a ``.tfm`` file."""
    return LPS_RAS @ np.linalg.inv(read_itk_tfm(path)) @ LPS_RAS


def write_slicer_tfm(path: str | os.PathLike, T_parent_from_child_ras) -> None:
    """Write a RAS "to parent" matrix as Slicer exports it (LPS, resampling direction)."""
    T = np.asarray(T_parent_from_child_ras, dtype=float)
    if T.shape != (4, 4):
        raise ValueError(f"T_parent_from_child_ras: expected a 4x4 matrix, got {T.shape}")
    write_itk_tfm(path, LPS_RAS @ np.linalg.inv(T) @ LPS_RAS)
