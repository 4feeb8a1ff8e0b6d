"""The study manifest schema (current version) and a small validator for it.

A study folder holds ``study.json``, the manifest. It *references* raw data (fluoro sequences,
camera files, CT volumes) by path — relative to the study folder when the data lies inside it,
absolute otherwise — and never copies it. Schema version :data:`SCHEMA_VERSION`::

    {
      "format": "talus-study",
      "schema_version": 2,
      "name": "subject 07",
      "created": "2025-01-31T10:00:00+00:00",          # ISO 8601, UTC
      "modified": "2025-01-31T10:05:00+00:00",
      "calibrations": {                                 # name -> one file per camera
        "day1": {"format": "mayacam", "cameras": ["calib/cam1.txt", "calib/cam2.txt"],
                 "pixel_size_mm": null}
      },
      "volumes": {                                      # CT sources (see core.io.read_ct)
        "foot_ct": {"path": "ct/foot", "voxel_size_mm": null, "hu_offset": 0.0,
                    "labels": "ct/foot_labels.nii.gz"}
      },
      "bones": {                                        # a bone = a volume (+ label) (+ margin)
        "talus": {"volume": "foot_ct", "label": 3, "margin_mm": 5.0}
      },
      "trials": {
        "walk01": {"calibration": "day1",
                   "views": [{"path": "raw/walk01_cam1.cine", "bit_depth": null},
                             {"path": "raw/walk01_cam2.cine", "bit_depth": null}],
                   "frame_offset": 0,                   # view 1 frame = trial frame + offset
                   "bones": ["talus"]}
      },
      "settings": {}                                    # free JSON object (app/CLI options)
    }

Validation reports the first problem as ``<file>: <json path>: expected ..., got ...``.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

from .errors import StudyError

__all__ = ["FORMAT", "MANIFEST_NAME", "SCHEMA_VERSION", "validate_manifest"]

FORMAT = "talus-study"
MANIFEST_NAME = "study.json"
SCHEMA_VERSION = 2
NAME_RE = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.\-]{0,63}")  # use fullmatch ("$" accepts a final newline)


def _show(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


@dataclass(frozen=True)
class _Rule:
    """One node of the schema: ``check(value, where)`` raises with a located message."""

    test: Callable[[Any], bool]
    expected: str

    def check(self, value: Any, where: str, fail: Callable[[str], None]) -> None:
        if not self.test(value):
            fail(f"{where}: expected {self.expected}, got {_show(value)}")


def _is_num(v: Any) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)


STR = _Rule(lambda v: isinstance(v, str) and v != "", "a non-empty string")
PATH = _Rule(lambda v: isinstance(v, str) and v.strip() != "" and "\x00" not in v, "a file path string")
INT = _Rule(lambda v: isinstance(v, int) and not isinstance(v, bool), "an integer")
NUM = _Rule(_is_num, "a finite number")
NONNEG = _Rule(lambda v: _is_num(v) and v >= 0, "a number >= 0")
POS = _Rule(lambda v: _is_num(v) and v > 0, "a number > 0")
BITS = _Rule(lambda v: v in (8, 10, 12, 14, 16) and not isinstance(v, bool), "one of 8, 10, 12, 14, 16")
VOXEL = _Rule(
    lambda v: isinstance(v, list) and len(v) == 3 and all(_is_num(x) and x > 0 for x in v),
    "a list of 3 positive voxel sizes (mm)",
)


@dataclass(frozen=True)
class _Obj:
    """A JSON object with required and optional keys; unknown keys are rejected."""

    required: Mapping[str, Any]
    optional: Mapping[str, Any] = field(default_factory=dict)
    nullable: frozenset[str] = frozenset()

    def check(self, value: Any, where: str, fail: Callable[[str], None]) -> None:
        if not isinstance(value, dict):
            fail(f"{where}: expected a JSON object, got {_show(value)}")
        for key in value:
            if key not in self.required and key not in self.optional:
                allowed = sorted([*self.required, *self.optional])
                fail(f"{where}: unknown key {key!r} (allowed: {', '.join(allowed)})")
        for key, rule in self.required.items():
            if key not in value:
                fail(f"{where}: missing required key {key!r}")
            self._one(key, rule, value[key], where, fail)
        for key, rule in self.optional.items():
            if key in value:
                self._one(key, rule, value[key], where, fail)

    def _one(self, key, rule, item, where, fail) -> None:
        if item is None and key in self.nullable:
            return
        rule.check(item, f"{where}.{key}" if where else key, fail)


@dataclass(frozen=True)
class _List:
    item: Any
    min_len: int = 0

    def check(self, value: Any, where: str, fail: Callable[[str], None]) -> None:
        if not isinstance(value, list) or len(value) < self.min_len:
            fail(f"{where}: expected a list of at least {self.min_len} item(s), got {_show(value)}")
        for i, item in enumerate(value):
            self.item.check(item, f"{where}[{i}]", fail)


@dataclass(frozen=True)
class _Map:
    """A JSON object used as a name -> entry table; names must match :data:`NAME_RE`."""

    item: Any

    def check(self, value: Any, where: str, fail: Callable[[str], None]) -> None:
        if not isinstance(value, dict):
            fail(f"{where}: expected a JSON object of named entries, got {_show(value)}")
        for name, item in value.items():
            if not NAME_RE.fullmatch(name):
                fail(
                    f"{where}: entry name {name!r} must be 1-64 letters, digits, '_', '-', '.' "
                    "starting with a letter or digit"
                )
            self.item.check(item, f"{where}[{name!r}]", fail)


@dataclass(frozen=True)
class _Const:
    value: Any

    def check(self, value: Any, where: str, fail: Callable[[str], None]) -> None:
        if value != self.value:
            fail(f"{where}: expected {self.value!r}, got {_show(value)}")


_ANY_OBJECT = _Rule(lambda v: isinstance(v, dict), "a JSON object")

MANIFEST = _Obj(
    required={
        "format": _Const(FORMAT),
        "schema_version": _Const(SCHEMA_VERSION),
        "name": STR,
        "created": STR,
        "modified": STR,
        "calibrations": _Map(
            _Obj(
                required={"format": _Const("mayacam"), "cameras": _List(PATH, min_len=1)},
                optional={"pixel_size_mm": POS},
                nullable=frozenset({"pixel_size_mm"}),
            )
        ),
        "volumes": _Map(
            _Obj(
                required={"path": PATH},
                optional={"voxel_size_mm": VOXEL, "hu_offset": NUM, "labels": PATH},
                nullable=frozenset({"voxel_size_mm", "labels"}),
            )
        ),
        "bones": _Map(
            _Obj(
                required={"volume": STR},
                optional={"label": INT, "margin_mm": NONNEG},
                nullable=frozenset({"label"}),
            )
        ),
        "trials": _Map(
            _Obj(
                required={
                    "calibration": STR,
                    "views": _List(
                        _Obj(
                            required={"path": PATH},
                            optional={"bit_depth": BITS},
                            nullable=frozenset({"bit_depth"}),
                        ),
                        min_len=1,
                    ),
                },
                optional={"frame_offset": INT, "bones": _List(STR)},
            )
        ),
        "settings": _ANY_OBJECT,
    }
)


def validate_manifest(doc: Any, *, source: str = "study.json") -> None:
    """Check a manifest of the current schema version; raise :class:`StudyError` if invalid.

    Besides the structure, cross-references are checked: each bone's volume, each trial's
    calibration and bones exist, and a trial has as many views as its calibration has cameras.

    Parameters
    ----------
    doc : object
        The parsed JSON document.
    source : str
        File name used in the error messages.
    """

    def fail(msg: str) -> None:
        raise StudyError(f"{source}: {msg}")

    MANIFEST.check(doc, "", lambda m: fail(m.lstrip(": ") if m.startswith(":") else m))
    for name, bone in doc["bones"].items():
        if bone["volume"] not in doc["volumes"]:
            have = sorted(doc["volumes"])
            fail(f"bones[{name!r}].volume: no volume named {bone['volume']!r} (have {have})")
    for name, trial in doc["trials"].items():
        cal = trial["calibration"]
        if cal not in doc["calibrations"]:
            have = sorted(doc["calibrations"])
            fail(f"trials[{name!r}].calibration: no calibration named {cal!r} (have {have})")
        n_cams = len(doc["calibrations"][cal]["cameras"])
        if len(trial["views"]) != n_cams:
            fail(
                f"trials[{name!r}].views: expected {n_cams} view(s), one per camera of calibration "
                f"{cal!r}, got {len(trial['views'])}"
            )
        for i, bone in enumerate(trial.get("bones", [])):
            if bone not in doc["bones"]:
                fail(f"trials[{name!r}].bones[{i}]: no bone named {bone!r} (have {sorted(doc['bones'])})")
