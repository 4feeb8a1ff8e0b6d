"""The object frames of a calibration session after the beads step
(:func:`core.calibration.session.beads_step`): detections and labellings of both views, and
the edits the calibration wizard makes to them (a frame left out, a label corrected).

Pixels are ``(u, v) = (column, row)``, origin at the centre of the top-left pixel.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from .bundle import ObjectFrame
from .matching import FrameLabels


@dataclass(frozen=True, eq=False)
class BeadsStep:
    """The object frames: detections and labellings of both views.

    ``frames`` / ``static_frames`` are :class:`~core.calibration.matching.FrameLabels` per frame,
    ``detections`` / ``static_detections`` the ``(view 1, view 2)`` detections, ``refs`` /
    ``static_refs`` the frame references per camera, ``excluded`` the frame indices (of ``frames``)
    left out by hand. :func:`exclude_frames` and :func:`relabel` give edited copies.
    """

    frames: list
    detections: list
    refs: list
    static_frames: list
    static_detections: list
    static_refs: list
    F: np.ndarray
    excluded: frozenset = frozenset()

    def rows(self) -> tuple[list, list]:
        """Per-frame report rows (``group``, ``index``, ``files``, ``ok``, ``reason``, ``labelled``)."""
        out = []
        for group, frames, refs in (("spiral", self.frames, self.refs), ("cube", self.static_frames,
                                                                          self.static_refs)):
            rows = []
            for k, fr in enumerate(frames):
                ex = group == "spiral" and k in self.excluded
                rows.append({"group": group, "index": k, "files": [str(r[k]) for r in refs],
                             "ok": bool(fr.ok) and not ex,
                             "reason": "excluded by hand" if ex else fr.reason,
                             "labelled": [int(lab.n_labelled) for lab in fr.labellings]})
                if any(lab.manual for lab in fr.labellings):
                    rows[-1]["manual"] = True
            out.append(rows)
        return out[0], out[1]

    def observations(self, target, static) -> tuple[list, list]:
        obs = [ObjectFrame(target.centers, np.stack([lab.observed() for lab in fr.labellings]))
               for k, fr in enumerate(self.frames) if fr.ok and k not in self.excluded]
        sobs = [ObjectFrame(static.centers, np.stack([lab.observed() for lab in fr.labellings]))
                for fr in self.static_frames if fr.ok]
        return obs, sobs


def exclude_frames(beads: BeadsStep, frames) -> BeadsStep:
    """A copy of ``beads`` with the object frames ``frames`` (indices) left out of the solve."""
    idx = frozenset(int(k) for k in frames)
    bad = [k for k in idx if not 0 <= k < len(beads.frames)]
    if bad:
        raise ValueError(f"frames: indices {sorted(bad)} are not in [0, {len(beads.frames)})")
    return replace(beads, excluded=idx)


def relabel(beads: BeadsStep, frame: int, view: int, detection: int, bead: int,
            *, min_labelled: int = 6) -> BeadsStep:
    """A copy of ``beads`` in which detection ``detection`` of view ``view`` of object frame
    ``frame`` is bead ``bead`` (model index) — :meth:`~core.calibration.labelling.Labelling.assign`,
    the manual correction of a wrong label. A frame with at least ``min_labelled`` labels in both
    views counts as labelled after the edit."""
    if not 0 <= int(frame) < len(beads.frames):
        raise ValueError(f"frame: expected an index in [0, {len(beads.frames)}), got {frame!r}")
    fr = beads.frames[int(frame)]
    if view not in (0, 1):
        raise ValueError(f"view: expected 0 or 1, got {view!r}")
    labs = list(fr.labellings)
    labs[view] = labs[view].assign(detection, bead)
    ok = all(lab.n_labelled >= min_labelled for lab in labs)
    new = FrameLabels(tuple(labs), ok, "" if ok else f"fewer than {min_labelled} labelled beads in a view",
                      fr.distance_px)
    frames = list(beads.frames)
    frames[int(frame)] = new
    return replace(beads, frames=frames)
