"""The generator's own image correction of a demo folder, for studies that compare with the truth.

Only studies read it (never a user's path): :mod:`core.studies.calibration.tracking_comparison`
tracks a trial corrected by it beside one corrected by the study's saved calibration, and
:mod:`core.studies.tracking.jcs_check` tracks frames corrected by it.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

__all__ = ["true_correction"]


def true_correction(folder: Path, names) -> list:
    """The generator's flatfield and distortion of each view (``imaging/`` of the demo folder)."""
    import tifffile

    from core.synthetic.distortion import Distortion

    out = []
    for name in names:
        meta = json.loads((folder / "imaging" / f"{name}.json").read_text())
        dark = float(meta.get("dark_dn", 0.0))
        gain = tifffile.imread(folder / "imaging" / f"flatfield_{name}.tif").astype(np.float64) - dark
        d = meta.get("distortion")
        dist = None if not d else Distortion(tuple(d["center"]), d["scale_px"], d["k1"], d["k2"],
                                             d["twist_rad"], d["twist_power"])

        def correct(raw, gain=gain, dark=dark, dist=dist):
            ok = gain > 1e-6
            img = np.where(ok, (np.asarray(raw, np.float64) - dark) / np.where(ok, gain, 1.0), 0.0)
            img = np.clip(img, 0.0, 1.0).astype(np.float32)
            return dist.unwarp(img) if dist is not None else img

        out.append(correct)
    return out
