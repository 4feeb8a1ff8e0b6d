"""Triangle surface meshes (bone models): STL, PLY, OBJ and VTP, without VTK.

* STL (binary or ASCII) is parsed here: binary = 80-byte header, ``uint32`` triangle count,
  then per triangle 12 ``float32`` (normal, three vertices) and a ``uint16`` attribute; ASCII =
  ``facet normal`` / ``outer loop`` / three ``vertex x y z`` lines. Identical vertex positions are
  merged so that the result is an indexed mesh.
* PLY and OBJ are read and written with meshio; polygons are fan-triangulated.
* VTP (VTK XML PolyData) is handled by :mod:`core.io.vtp`.

Coordinates are taken as millimetres in the model's own frame (the CT physical frame for
segmentations exported from the CT); nothing is rescaled.
"""

from __future__ import annotations

import contextlib
import io
import os
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .atomic import atomic_path, atomic_write
from .errors import reads
from .vtp import read_vtp, write_vtp

__all__ = ["Mesh", "read_mesh", "write_mesh"]

_SUFFIXES = (".stl", ".ply", ".obj", ".vtp")
_STL_DTYPE = np.dtype([("normal", "<f4", 3), ("v", "<f4", (3, 3)), ("attr", "<u2")])


@dataclass(frozen=True, eq=False)
class Mesh:
    """An indexed triangle mesh.

    Parameters
    ----------
    vertices : (N, 3) array
        Vertex positions, mm.
    faces : (M, 3) int array
        Triangles as indices into ``vertices`` (counter-clockwise seen from outside for a
        well-oriented closed surface).
    name : str
    """

    vertices: np.ndarray
    faces: np.ndarray
    name: str = ""

    def __post_init__(self) -> None:
        V = np.asarray(self.vertices, dtype=np.float64)
        F = np.asarray(self.faces)
        if V.ndim != 2 or V.shape[1] != 3 or not np.all(np.isfinite(V)):
            raise ValueError(f"vertices: expected finite (N, 3) positions, got shape {V.shape}")
        if F.ndim != 2 or F.shape[1] != 3 or not (np.issubdtype(F.dtype, np.integer) or F.size == 0):
            raise ValueError(f"faces: expected (M, 3) integer vertex indices, got {F.shape} {F.dtype}")
        F = F.astype(np.int64)
        if F.size and (F.min() < 0 or F.max() >= len(V)):
            raise ValueError(f"faces: indices must lie in [0, {len(V) - 1}], got {F.min()}..{F.max()}")
        for name, arr in (("vertices", V), ("faces", F)):
            arr = arr.copy()
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)

    @property
    def n_vertices(self) -> int:
        return len(self.vertices)

    @property
    def n_faces(self) -> int:
        return len(self.faces)

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """``(min xyz, max xyz)`` in mm."""
        return self.vertices.min(axis=0), self.vertices.max(axis=0)

    def area(self) -> float:
        """Total surface area, mm²."""
        a, b, c = (self.vertices[self.faces[:, k]] for k in range(3))
        return float(0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1).sum())

    def volume(self) -> float:
        """Signed enclosed volume, mm³ (positive for an outward-oriented closed surface)."""
        a, b, c = (self.vertices[self.faces[:, k]] for k in range(3))
        return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)

    def transformed(self, T) -> Mesh:
        """The mesh moved by a 4x4 rigid transform (e.g. ``T_lab_from_bone``)."""
        from .._validate import check_rigid

        T = check_rigid(T, "T")
        return Mesh(self.vertices @ T[:3, :3].T + T[:3, 3], self.faces, self.name)


def _merge(tri_vertices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Indexed mesh from ``(M, 3, 3)`` per-triangle vertex positions (exact duplicates merged)."""
    flat = tri_vertices.reshape(-1, 3).astype(np.float64)
    V, inverse = np.unique(flat, axis=0, return_inverse=True)
    return V, inverse.reshape(-1, 3).astype(np.int64)


def _read_stl(path: Path) -> tuple[np.ndarray, np.ndarray]:
    data = path.read_bytes()
    if len(data) >= 84:
        n = int(np.frombuffer(data, "<u4", count=1, offset=80)[0])
        if len(data) == 84 + 50 * n:
            tris = np.frombuffer(data, _STL_DTYPE, count=n, offset=84)["v"]
            if not np.all(np.isfinite(tris)):
                raise ValueError(f"{path}: binary STL with non-finite vertex coordinates")
            if n == 0:
                raise ValueError(f"{path}: binary STL with no triangles")
            return _merge(tris)
    head = data[:512].lstrip().lower()
    if not head.startswith(b"solid"):
        size = f"{len(data)} bytes"
        raise ValueError(
            f"{path}: neither a binary STL (size {size} does not match 84 + 50 x triangle count) nor an "
            "ASCII STL (no leading 'solid')"
        )
    try:
        text = data.decode("ascii")
    except UnicodeDecodeError:
        raise ValueError(f"{path}: ASCII STL with non-ASCII bytes (or a truncated binary STL)") from None
    verts = []
    for lineno, line in enumerate(text.splitlines(), start=1):
        tok = line.split()
        if tok and tok[0] == "vertex":
            try:
                xyz = [float(t) for t in tok[1:4]]
            except ValueError:
                xyz = []
            if len(tok) != 4 or len(xyz) != 3 or not np.all(np.isfinite(xyz)):
                raise ValueError(f"{path}: line {lineno}: expected 'vertex x y z', got {line.strip()!r}")
            verts.append(xyz)
    if not verts or len(verts) % 3:
        raise ValueError(
            f"{path}: ASCII STL with {len(verts)} vertex lines; expected 3 per facet (>= 1 facet)"
        )
    return _merge(np.array(verts).reshape(-1, 3, 3))


def _write_stl(path: Path, V: np.ndarray, F: np.ndarray, binary: bool) -> None:
    tri = V[F]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    norm = np.linalg.norm(n, axis=1, keepdims=True)
    n = np.divide(n, norm, out=np.zeros_like(n), where=norm > 0)
    if binary:
        rec = np.zeros(len(F), _STL_DTYPE)
        rec["normal"], rec["v"] = n, tri
        header = b"Talus binary STL".ljust(80, b" ")
        atomic_write(path, header + np.array([len(F)], "<u4").tobytes() + rec.tobytes())
        return
    lines = ["solid talus"]
    for nn, t in zip(n, tri, strict=True):
        lines += [f"facet normal {nn[0]!r} {nn[1]!r} {nn[2]!r}", "outer loop"]
        lines += [f"vertex {p[0]!r} {p[1]!r} {p[2]!r}" for p in t.tolist()]
        lines += ["endloop", "endfacet"]
    atomic_write(path, "\n".join([*lines, "endsolid talus"]) + "\n")


def _read_meshio(path: Path, fmt: str) -> tuple[np.ndarray, np.ndarray]:
    import meshio

    if fmt == "ply":  # meshio reads header lines forever when "end_header" is missing
        with open(path, "rb") as fh:
            head = fh.read(1 << 16)
        if not head.startswith(b"ply") or b"end_header" not in head:
            raise ValueError(f"{path}: expected a PLY header ('ply' ... 'end_header' in the first 64 kB)")
    said = io.StringIO()
    try:
        with warnings.catch_warnings(), np.errstate(all="ignore"), contextlib.redirect_stdout(said):
            warnings.simplefilter("ignore")
            m = meshio.read(path, file_format=fmt)
    except (Exception, SystemExit) as exc:  # meshio raises many types, and exits on some PLY headers
        why = f"{type(exc).__name__}: {exc}" if not isinstance(exc, SystemExit) else said.getvalue().strip()
        raise ValueError(f"{path}: cannot read as {fmt.upper()} ({why})") from None
    faces = []
    for block in m.cells:
        data = np.asarray(block.data)
        if block.type in ("triangle", "quad", "polygon") or (data.ndim == 2 and data.shape[1] >= 3):
            if data.ndim == 2 and data.shape[1] >= 3:
                faces += [data[:, [0, k, k + 1]] for k in range(1, data.shape[1] - 1)]
    if not faces:
        raise ValueError(f"{path}: no triangles or polygons in the {fmt.upper()} file")
    return np.asarray(m.points, dtype=np.float64)[:, :3], np.concatenate(faces).astype(np.int64)


@reads("a triangle mesh (.stl, .ply, .obj or .vtp)")
def read_mesh(path: str | os.PathLike, *, name: str | None = None) -> Mesh:
    """Read a triangle surface from ``.stl``, ``.ply``, ``.obj`` or ``.vtp``.

    Raises
    ------
    ValueError
        Missing or unsupported file, or a damaged one (the message names the file).
    """
    p = Path(path)
    suffix = p.suffix.lower()
    if suffix not in _SUFFIXES:
        raise ValueError(f"path: {p} is not a mesh file; expected one of {', '.join(_SUFFIXES)}")
    if not p.is_file():
        raise ValueError(f"path: no such mesh file: {p}")
    if suffix == ".stl":
        V, F = _read_stl(p)
    elif suffix == ".vtp":
        V, F = read_vtp(p)
    else:
        V, F = _read_meshio(p, suffix[1:])
    try:
        return Mesh(V, F, name or p.stem)
    except ValueError as exc:
        raise ValueError(f"{p}: {exc}") from None


def write_mesh(mesh: Mesh, path: str | os.PathLike, *, binary: bool = True) -> None:
    """Write a mesh (format from the suffix: ``.stl``, ``.ply``, ``.obj``, ``.vtp``) atomically.

    ``binary`` selects binary STL/PLY/VTP (base64) or their text forms; OBJ is always text.
    """
    if not isinstance(mesh, Mesh):
        raise ValueError(f"mesh: expected a Mesh, got {type(mesh).__name__}")
    p = Path(path)
    suffix = p.suffix.lower()
    if suffix not in _SUFFIXES:
        raise ValueError(f"path: expected a .stl, .ply, .obj or .vtp file name, got {p.name}")
    V, F = mesh.vertices, mesh.faces
    if suffix == ".stl":
        _write_stl(p, V, F, binary)
        return
    with atomic_path(p) as tmp:
        if suffix == ".vtp":
            write_vtp(tmp, V, F, binary=binary)
        else:
            import meshio

            m = meshio.Mesh(V, [("triangle", F.astype(np.int32))])
            kw = {"binary": binary} if suffix == ".ply" else {}
            meshio.write(tmp, m, file_format=suffix[1:], **kw)
