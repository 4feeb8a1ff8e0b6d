"""Reading a calibration session for :mod:`core.calibration.session`: its errors, the checked
frame reader, the manifest's kV sets, detector pixel size and lab transform, and the objects.

Pixels are ``(u, v) = (column, row)``, origin at the centre of the top-left pixel; mm.
"""

from __future__ import annotations

import numpy as np

from .objects import CalibrationTarget, builtin_target, read_target

#: Defaults when the session manifest does not say (the built-in hole grid, spiral and cube).
DEFAULTS = {"pitch_mm": 15.0, "hole_diameter_mm": 3.0, "object": "spiral33", "static_object": "cube15",
            "magnification": (1.1, 1.5, 2.0)}


class SessionError(ValueError):
    """A calibration step could not run on the session's input.

    Attributes: ``step`` (``"session"``, ``"flatfield"``, ``"distortion"``, ``"beads"``,
    ``"bundle"``), ``where`` (file and frame, or camera), ``hint`` (what can be done).
    """

    def __init__(self, step: str, where: str, what: str, hint: str = ""):
        msg = f"{step}: {where}: {what}" + (f". {hint}" if hint else "")
        super().__init__(msg)
        self.step, self.where, self.what, self.hint = step, where, what, hint


class CalibrationCancelled(Exception):
    """``cancel()`` returned True; nothing was saved."""

# ---------------------------------------------------------------------------- input
def _target(spec, what: str) -> CalibrationTarget:
    if isinstance(spec, CalibrationTarget):
        return spec
    s = str(spec)
    try:
        if s.lower().endswith((".csv", ".json")):
            return read_target(s)
        return builtin_target(s)
    except (ValueError, OSError) as exc:
        raise SessionError("session", what, f"cannot use calibration object {s!r} ({exc})",
                           "name a built-in object (spiral23, spiral33, cube15) or an object file "
                           "(.csv/.json)") from None


class _Reader:
    """Frames of the session with checks: a missing group, an unreadable file, a wrong size."""

    def __init__(self, session, cancel):
        self.s, self.cancel, self.shape = session, cancel, {}

    def refs(self, cam: str, group: str, *, required: bool = True) -> list:
        try:
            refs = list(self.s.frames(cam, group))
        except (KeyError, ValueError, OSError, FileNotFoundError) as exc:
            refs, why = [], str(exc)
        else:
            why = "no frames"
        if not refs and required:
            raise SessionError("session", f"camera {cam}, {group!r} frames", f"missing ({why})",
                               f"record the {group!r} frames of camera {cam} or remove the camera "
                               "from the session manifest")
        return refs

    def read(self, cam: str, ref, k: int, step: str) -> np.ndarray:
        if self.cancel is not None and self.cancel():
            raise CalibrationCancelled(f"cancelled during {step}")
        try:
            img = np.asarray(self.s.read(ref), dtype=np.float32)
        except (OSError, ValueError) as exc:
            raise SessionError(step, f"{ref} (frame {k})", f"cannot read the frame ({exc})",
                               "replace or remove the file") from None
        if img.ndim != 2:
            raise SessionError(step, f"{ref} (frame {k})", f"expected a 2-D frame, got shape {img.shape}")
        want = self.shape.setdefault(cam, (img.shape, ref))
        if img.shape != want[0]:
            raise SessionError(step, f"{ref} (frame {k})",
                               f"frame of {img.shape[1]}x{img.shape[0]} pixels, but {want[1]} of the "
                               f"same camera has {want[0][1]}x{want[0][0]}",
                               "every frame of a camera must have one size: re-export the session "
                               "at the detector's full resolution")
        return img


def _flat_groups(session, cam: str) -> list[tuple[float | None, str]]:
    """``(kV, group)`` of the camera's empty-field frame sets."""
    kvs = getattr(session, "kvs", None)
    if kvs is None:
        man = getattr(session, "manifest", {}) or {}
        kvs = man.get("flat_kv") or man.get("kv") or []
        kvs = [kvs] if isinstance(kvs, int | float) else kvs
    return [(float(k), f"flat:{float(k):g}") for k in kvs]


def _pixel_size(man: dict) -> float | None:
    px = (man.get("detector") or {}).get("pixel_size_mm", man.get("pixel_size_mm"))
    try:
        return float(px) if px is not None and float(px) > 0 else None
    except (TypeError, ValueError):
        return None


def _manifest_T(man: dict) -> np.ndarray | None:
    T = man.get("T_lab_from_static_object") or man.get("lab_from_cube")
    if T is None:
        return None
    T = np.asarray(T, float)
    return T if T.shape == (4, 4) and np.all(np.isfinite(T)) else None
