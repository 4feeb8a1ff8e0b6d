"""Calibration objects: bead geometry, definition files, built-ins (thesis §5.3).

A :class:`CalibrationTarget` is what calibration needs to know about an object: an identifier,
centre (object frame, mm) and diameter (mm) of every bead, the object's kind (``"spiral"``,
``"cube"`` or ``"generic"``; it selects the labelling algorithm), a sentence defining the object
frame, and free metadata. The geometry of the built-ins is not duplicated here: it comes from
:mod:`core.calibration.hardware` (the same objects the synthetic frames are rendered from).

Built-ins
---------
* ``"cube15"``: the lab's old cube, three planes of five beads of 1.78, 3.17 and 4.76 mm.
* ``"spiral23"`` / ``"spiral33"``: helical spirals of beads alternating 3.0 / 5.0 mm
  (:func:`spiral_target` takes any count, radius, pitch and turns). Object frame (§5.3.2):
  z along the helix axis from the first to the last bead, x from the axis towards the first
  bead, origin on the axis half-way between the end beads.

Definition file (``.csv``; UTF-8 text)
--------------------------------------
::

    # talus calibration object v1
    # name: spiral23
    # kind: spiral
    # units: mm
    # frame: z along the helix axis ...
    # meta.material: stainless steel
    id,x,y,z,diameter
    B01,30.0,0.0,-60.0,3.0
    ...

Lines starting with ``#`` hold ``key: value`` pairs (``meta.<key>`` goes to ``metadata``); the
first non-comment line is the header ``id,x,y,z,diameter`` (any column order), then one bead per
line. Coordinates and diameters are in millimetres. The same content as JSON (``.json``) is
:meth:`CalibrationTarget.to_dict`.

Bead coordinates from a micro-CT scan of an object: :mod:`core.calibration.microct`.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .._validate import as_float_array
from ..io.atomic import atomic_write
from ..render.attenuation import attenuation_per_mm
from .hardware import CalibrationObject, calibration_cube, helical_spiral

__all__ = [
    "KINDS",
    "CalibrationTarget",
    "builtin_target",
    "cube_target",
    "read_target",
    "spiral_target",
    "write_target",
]

#: Object kinds understood by the labelling step.
KINDS = ("spiral", "cube", "generic")
FORMAT_NAME = "talus calibration object"
FORMAT_VERSION = 1
_HELIX_FRAME = ("z along the helix axis from the first to the last bead; x from the axis towards "
                "the first bead; origin on the axis half-way between the end beads (thesis 5.3.2)")
_CUBE_FRAME = ("origin at the block centre; z normal to the three bead planes (z = -30, 0, +30 mm "
               "for 1.78, 3.17, 4.76 mm beads); x, y along the block edges")


@dataclass(frozen=True, eq=False)
class CalibrationTarget:
    """Beads of a calibration object in its own frame.

    Parameters
    ----------
    name : str
        Object name (e.g. ``"spiral23"``).
    bead_ids : sequence of str
        Unique identifier of each bead (e.g. ``"B01"``), in model order (along the helix for a
        spiral).
    centers : (n, 3) array
        Bead centres in the object frame, mm.
    diameters : (n,) array
        Bead diameters, mm.
    kind : {"spiral", "cube", "generic"}
        Selects the labelling algorithm.
    frame : str
        How the object frame is defined (free text, stored with the object).
    metadata : dict
        Free JSON-serialisable metadata (material, serial number, scan date, ...).
    body : tuple, optional
        The homogeneous body of a built-in (see :class:`core.calibration.hardware.CalibrationObject`), used
        only to render synthetic frames.
    """

    name: str
    bead_ids: tuple[str, ...]
    centers: np.ndarray
    diameters: np.ndarray
    kind: str = "generic"
    frame: str = ""
    metadata: dict[str, Any] = field(default_factory=dict)
    body: tuple | None = None

    def __post_init__(self) -> None:
        c = as_float_array(self.centers, "centers", shape=(None, 3))
        n = len(c)
        d = as_float_array(self.diameters, "diameters")
        d = np.broadcast_to(d, (n,)).astype(float) if d.ndim == 0 else d
        if d.shape != (n,):
            raise ValueError(f"diameters: expected {n} values (one per bead), got shape {d.shape}")
        if np.any(d <= 0):
            raise ValueError("diameters: expected positive bead diameters in mm")
        ids = tuple(str(i) for i in self.bead_ids)
        if len(ids) != n:
            raise ValueError(f"bead_ids: expected {n} identifiers (one per bead), got {len(ids)}")
        if len(set(ids)) != n or any(not i.strip() or "," in i for i in ids):
            raise ValueError("bead_ids: expected unique, non-empty identifiers without commas")
        if n < 1:
            raise ValueError("centers: expected at least one bead")
        if self.kind not in KINDS:
            raise ValueError(f"kind: expected one of {KINDS}, got {self.kind!r}")
        if not isinstance(self.metadata, dict):
            raise ValueError(f"metadata: expected a dict, got {type(self.metadata).__name__}")
        for nm, arr in (("centers", c), ("diameters", d)):
            arr = arr.copy()
            arr.setflags(write=False)
            object.__setattr__(self, nm, arr)
        object.__setattr__(self, "bead_ids", ids)
        object.__setattr__(self, "metadata", dict(self.metadata))

    def __len__(self) -> int:
        return len(self.centers)

    def index(self, bead_id: str) -> int:
        """Model index of ``bead_id`` (raises ``ValueError`` naming the unknown id)."""
        try:
            return self.bead_ids.index(str(bead_id))
        except ValueError:
            raise ValueError(f"bead_id: {bead_id!r} is not a bead of {self.name!r}") from None

    @property
    def size_classes(self) -> tuple[np.ndarray, np.ndarray]:
        """``(sizes (k,), class_of_bead (n,))``: the distinct diameters (ascending, mm, merged
        within 5 %) and the class index of every bead."""
        order = np.sort(self.diameters)
        sizes = [order[0]]
        for d in order[1:]:
            if d > 1.05 * sizes[-1]:
                sizes.append(d)
        sizes = np.array(sizes)
        cls = np.argmin(np.abs(np.log(self.diameters[:, None] / sizes[None])), axis=1)
        return sizes, cls

    @property
    def symmetries(self) -> tuple[np.ndarray, ...]:
        """Label permutations ``π`` (identity first) under which the object is unchanged: a rigid
        motion maps bead ``k`` onto bead ``π[k]`` (within 1 µm) with the same diameter.

        A helix of strictly alternating beads with an odd count is symmetric under a half-turn
        about an axis through its middle bead (``π = reversed``): images cannot tell its two
        ends apart, so a labelling is only defined up to these permutations.
        """
        n = len(self)
        out = [np.arange(n)]
        rev = np.arange(n)[::-1]
        if n >= 3 and np.array_equal(self.diameters, self.diameters[rev]):
            from ..markers.pose import rigid_fit

            fit = rigid_fit(self.centers, self.centers[rev])
            if np.isfinite(fit.rms) and np.nanmax(fit.residuals) < 1e-3:
                out.append(rev)
        return tuple(out)

    def centers_lab(self, T_lab_from_object) -> np.ndarray:
        """Bead centres in the lab (mm) for the object pose ``T_lab_from_object`` (4x4)."""
        T = as_float_array(T_lab_from_object, "T_lab_from_object", shape=(4, 4))
        return self.centers @ T[:3, :3].T + T[:3, 3]

    def to_synthetic(self, *, energy_kev: float = 60.0, with_body: bool = True) -> CalibrationObject:
        """The :class:`~core.calibration.hardware.CalibrationObject` to render frames of this target (steel
        beads at ``energy_kev``; the built-in body unless ``with_body=False``)."""
        return CalibrationObject(self.name, self.centers, self.diameters,
                                 attenuation_per_mm("steel", energy_kev),
                                 self.body if with_body else None)

    def to_dict(self) -> dict:
        """JSON-ready description (the ``.json`` definition file)."""
        return {
            "format": FORMAT_NAME, "version": FORMAT_VERSION, "name": self.name, "kind": self.kind,
            "units": "mm", "frame": self.frame, "metadata": self.metadata,
            "beads": [{"id": i, "x": float(c[0]), "y": float(c[1]), "z": float(c[2]),
                       "diameter": float(d)}
                      for i, c, d in zip(self.bead_ids, self.centers, self.diameters, strict=True)],
        }

    @classmethod
    def from_dict(cls, d: dict, *, source: str = "target") -> CalibrationTarget:
        """Inverse of :meth:`to_dict`; errors name ``source`` and the bad key."""
        if not isinstance(d, dict):
            raise ValueError(f"{source}: expected a JSON object, got {type(d).__name__}")
        ver = d.get("version")
        if ver != FORMAT_VERSION:
            raise ValueError(f"{source}: unsupported calibration object version {ver!r} "
                             f"(this Talus reads version {FORMAT_VERSION})")
        if d.get("units", "mm") != "mm":
            raise ValueError(f"{source}: units: expected 'mm', got {d.get('units')!r}")
        beads = d.get("beads")
        if not isinstance(beads, list) or not beads:
            raise ValueError(f"{source}: beads: expected a non-empty list of beads")
        try:
            ids = [b["id"] for b in beads]
            xyz = [[float(b["x"]), float(b["y"]), float(b["z"])] for b in beads]
            dia = [float(b["diameter"]) for b in beads]
        except (KeyError, TypeError, ValueError) as exc:
            raise ValueError(f"{source}: beads: each bead needs id, x, y, z, diameter ({exc!r})") from None
        try:
            return cls(str(d.get("name", "object")), ids, xyz, dia, kind=d.get("kind", "generic"),
                       frame=str(d.get("frame", "")), metadata=d.get("metadata") or {})
        except ValueError as exc:
            raise ValueError(f"{source}: {exc}") from None


# ---------------------------------------------------------------------------- built-ins
def _ids(n: int) -> list[str]:
    w = max(2, len(str(n)))
    return [f"B{k + 1:0{w}d}" for k in range(n)]


def cube_target(*, energy_kev: float = 60.0) -> CalibrationTarget:
    """The lab's old 15-bead cube (:func:`core.calibration.hardware.calibration_cube`)."""
    obj = calibration_cube(energy_kev=energy_kev)
    return CalibrationTarget(obj.name, _ids(len(obj)), obj.centers, obj.diameters, kind="cube",
                             frame=_CUBE_FRAME, metadata={"material": "R1/BB Butter-Board resin"},
                             body=obj.body)


def spiral_target(n_beads: int = 23, *, radius_mm: float | None = None, pitch_mm: float = 40.0,
                  turns: float | None = None, diameters=None, energy_kev: float = 60.0
                  ) -> CalibrationTarget:
    """A helical spiral (:func:`core.calibration.hardware.helical_spiral`; presets for 23 and 33 beads).

    Parameters
    ----------
    n_beads : int
        Number of beads (23 and 33 have presets; other counts need ``radius_mm`` and ``turns``).
    radius_mm, pitch_mm, turns : float
        Helix radius (mm), axial advance per turn (mm) and turns from the first to the last bead.
    diameters : sequence of float, optional
        Bead diameters (mm) along the helix; default alternating 3.0 / 5.0 mm.
    """
    obj = helical_spiral(n_beads, radius_mm=radius_mm, pitch_mm=pitch_mm, turns=turns,
                         diameters=diameters, energy_kev=energy_kev)
    meta = {"radius_mm": float(np.hypot(*obj.centers[0, :2])), "pitch_mm": float(pitch_mm),
            "material": "stainless steel beads in cast polyurethane foam"}
    return CalibrationTarget(obj.name, _ids(len(obj)), obj.centers, obj.diameters, kind="spiral",
                             frame=_HELIX_FRAME, metadata=meta, body=obj.body)


_BUILTINS = {"cube15": cube_target, "spiral23": lambda: spiral_target(23),
             "spiral33": lambda: spiral_target(33)}


def builtin_target(name: str) -> CalibrationTarget:
    """A built-in object by name: ``"cube15"``, ``"spiral23"`` or ``"spiral33"``."""
    if name not in _BUILTINS:
        raise ValueError(f"name: expected one of {sorted(_BUILTINS)}, got {name!r}")
    return _BUILTINS[name]()


# ---------------------------------------------------------------------------- files
def write_target(target: CalibrationTarget, path) -> None:
    """Write a definition file (``.csv`` or ``.json`` by extension), atomically."""
    if not isinstance(target, CalibrationTarget):
        raise ValueError(f"target: expected a CalibrationTarget, got {type(target).__name__}")
    p = Path(path)
    if p.suffix.lower() == ".json":
        atomic_write(p, json.dumps(target.to_dict(), indent=2) + "\n")
        return
    if p.suffix.lower() not in (".csv", ".txt"):
        raise ValueError(f"path: expected a .csv, .txt or .json file name, got {p.name!r}")
    lines = [f"# {FORMAT_NAME} v{FORMAT_VERSION}", f"# name: {target.name}", f"# kind: {target.kind}",
             "# units: mm", f"# frame: {target.frame}"]
    for k, v in target.metadata.items():
        lines.append(f"# meta.{k}: {json.dumps(v)}")
    lines.append("id,x,y,z,diameter")
    for i, c, d in zip(target.bead_ids, target.centers, target.diameters, strict=True):
        lines.append(",".join([i, *(repr(float(x)) for x in c), repr(float(d))]))
    atomic_write(p, "\n".join(lines) + "\n")


def _parse_csv(p: Path, text: str) -> dict:
    head: dict[str, Any] = {"metadata": {}}
    rows, header = [], None
    for ln, line in enumerate(text.splitlines(), start=1):
        s = line.strip()
        if not s:
            continue
        if s.startswith("#"):
            body = s[1:].strip()
            if body.lower().startswith(FORMAT_NAME):
                ver = body[len(FORMAT_NAME):].strip().lstrip("v")
                head["version"] = int(ver) if ver.isdigit() else ver
            elif ":" in body:
                k, v = (x.strip() for x in body.split(":", 1))
                if k.startswith("meta."):
                    try:
                        head["metadata"][k[5:]] = json.loads(v)
                    except json.JSONDecodeError:
                        head["metadata"][k[5:]] = v
                else:
                    head[k] = v
            continue
        cells = [c.strip() for c in s.split(",")]
        if header is None:
            header = [c.lower() for c in cells]
            missing = {"id", "x", "y", "z", "diameter"} - set(header)
            if missing:
                raise ValueError(f"{p}: line {ln}: header misses column(s) {sorted(missing)}; "
                                 "expected id,x,y,z,diameter")
            continue
        if len(cells) != len(header):
            raise ValueError(f"{p}: line {ln}: expected {len(header)} values, got {len(cells)}")
        rows.append((ln, dict(zip(header, cells, strict=True))))
    if header is None:
        raise ValueError(f"{p}: no bead table (header line id,x,y,z,diameter) found")
    head.setdefault("version", FORMAT_VERSION)
    beads = []
    for ln, r in rows:
        try:
            beads.append({"id": r["id"], **{k: float(r[k]) for k in ("x", "y", "z", "diameter")}})
        except ValueError:
            raise ValueError(f"{p}: line {ln}: expected numbers for x, y, z, diameter") from None
    head["beads"] = beads
    return head


def read_target(path) -> CalibrationTarget:
    """Read a definition file (``.csv``/``.txt`` table with ``#`` metadata, or ``.json``).

    Raises
    ------
    ValueError
        Naming the file (and line) on a missing file, bad header, non-numeric value, duplicate
        id, non-positive diameter or unsupported version.
    """
    p = Path(os.fspath(path))
    if not p.is_file():
        raise ValueError(f"path: no such calibration object file: {p}")
    text = p.read_text(encoding="utf-8-sig")
    if p.suffix.lower() == ".json":
        try:
            d = json.loads(text)
        except json.JSONDecodeError as exc:
            raise ValueError(f"{p}: not valid JSON ({exc.msg}, line {exc.lineno})") from None
    else:
        d = _parse_csv(p, text)
    return CalibrationTarget.from_dict(d, source=str(p))
