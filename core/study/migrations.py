"""Forward migrations of study manifests to the current schema version.

Each step ``_vN_to_vN+1`` takes a manifest of version N (already checked structurally for what
it reads) and returns one of version N+1; :func:`migrate` chains them. A manifest written by a
*newer* Talus (version above :data:`~core.study.schema.SCHEMA_VERSION`) is refused with an error
that says so: reading it could silently drop fields this version does not know.

Version history
---------------
1
    First development layout: a single calibration (``"cameras"``: list of MayaCam files),
    ``"bones"`` as a list of ``{"name", "ct", "label"}`` (one CT file per bone entry) and
    ``"trials"`` as a list of ``{"name", "views": [paths], "offset"}``.
2
    Named calibrations, CT volumes separated from bones (several bones share one labelled CT),
    trials as a name -> entry table with per-view options and ``frame_offset``.
"""

from __future__ import annotations

import copy
from collections.abc import Callable
from typing import Any

from .errors import StudyError
from .schema import FORMAT, SCHEMA_VERSION

__all__ = ["migrate", "schema_version_of"]


def schema_version_of(doc: Any, *, source: str = "study.json") -> int:
    """The ``schema_version`` of a parsed manifest; :class:`StudyError` if it is not a study."""
    if not isinstance(doc, dict):
        raise StudyError(
            f"{source}: expected a JSON object (a Talus study manifest), got {type(doc).__name__}"
        )
    if doc.get("format") != FORMAT:
        raise StudyError(
            f"{source}: format: expected {FORMAT!r}, got {doc.get('format')!r}; not a Talus study"
        )
    v = doc.get("schema_version")
    if not isinstance(v, int) or isinstance(v, bool) or v < 1:
        raise StudyError(f"{source}: schema_version: expected a positive integer, got {v!r}")
    return v


def _need(cond: bool, source: str, msg: str) -> None:
    if not cond:
        raise StudyError(f"{source}: (schema version 1) {msg}")


def _v1_to_v2(doc: dict, source: str) -> dict:
    def is_str(x) -> bool:
        return isinstance(x, str) and x != ""

    cams = doc.get("cameras")
    _need(isinstance(cams, list) and len(cams) >= 1 and all(is_str(c) for c in cams), source,
          "cameras: expected a list of MayaCam file paths")
    bones_in = doc.get("bones", [])
    trials_in = doc.get("trials", [])
    _need(isinstance(bones_in, list), source, "bones: expected a list")
    _need(isinstance(trials_in, list), source, "trials: expected a list")
    volumes: dict[str, dict] = {}
    by_path: dict[str, str] = {}
    bones: dict[str, dict] = {}
    for i, b in enumerate(bones_in):
        ok = isinstance(b, dict) and is_str(b.get("name")) and is_str(b.get("ct"))
        _need(ok, source, f"bones[{i}]: expected name and ct (strings)")
        path = b["ct"]
        if path not in by_path:
            vname = f"ct{len(by_path) + 1}"
            by_path[path] = vname
            entry: dict[str, Any] = {"path": path}
            if b.get("voxel_size_mm") is not None:
                entry["voxel_size_mm"] = b["voxel_size_mm"]
            volumes[vname] = entry
        bones[b["name"]] = {"volume": by_path[path], "label": b.get("label"), "margin_mm": 5.0}
    trials: dict[str, dict] = {}
    for i, t in enumerate(trials_in):
        ok = isinstance(t, dict) and is_str(t.get("name")) and isinstance(t.get("views"), list)
        _need(ok, source, f"trials[{i}]: expected name and views")
        trials[t["name"]] = {
            "calibration": "default",
            "views": [{"path": p, "bit_depth": None} for p in t["views"]],
            "frame_offset": t.get("offset", 0),
            "bones": list(bones),
        }
    return {
        "format": FORMAT,
        "schema_version": 2,
        "name": doc.get("name", "study"),
        "created": doc.get("created", ""),
        "modified": doc.get("modified", ""),
        "calibrations": {
            "default": {"format": "mayacam", "cameras": list(cams), "pixel_size_mm": doc.get("pixel_size_mm")}
        },
        "volumes": volumes,
        "bones": bones,
        "trials": trials,
        "settings": doc.get("settings", {}),
    }


_STEPS: dict[int, Callable[[dict, str], dict]] = {1: _v1_to_v2}


def migrate(doc: Any, *, source: str = "study.json") -> tuple[dict, int]:
    """Bring a manifest to :data:`SCHEMA_VERSION`.

    Parameters
    ----------
    doc : dict
        A parsed manifest of any known version (not modified).
    source : str
        File name for the error messages.

    Returns
    -------
    doc : dict
        A new manifest of the current version (not yet validated).
    from_version : int
        The version ``doc`` had.

    Raises
    ------
    StudyError
        For a non-study document, a future version, or a version-1 document missing what the
        migration needs.
    """
    version = schema_version_of(doc, source=source)
    if version > SCHEMA_VERSION:
        raise StudyError(
            f"{source}: schema_version {version} was written by a newer Talus; this version reads "
            f"study manifests up to schema version {SCHEMA_VERSION}: upgrade Talus to open it"
        )
    out = copy.deepcopy(doc)
    for v in range(version, SCHEMA_VERSION):
        try:
            out = _STEPS[v](out, source)
        except (TypeError, KeyError, AttributeError) as exc:  # malformed old manifest
            raise StudyError(f"{source}: (schema version {v}) malformed manifest ({exc!r})") from None
    return out, version
