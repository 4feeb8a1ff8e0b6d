"""The acceptance study's count of frames over 4x the Cramér–Rao bound (flagged or silent)."""

from types import SimpleNamespace

import numpy as np

from core.studies.tracking.acceptance import _over_bound


def test_over_bound_counts_silent_and_false_flags():
    bound = {"rms_mm": 0.01, "rms_deg": 0.1}
    E = np.zeros((5, 6))
    E[1, :3] = [0.05, 0.0, 0.0]      # 5x in translation, flagged
    E[2, 3:] = [0.0, 0.0, -0.45]     # 4.5x in rotation, not flagged: silent
    E[3, :3] = [0.02, 0.02, 0.02]    # 3.5x: not over
    frames = [0, 1, 2, 3, 5]         # frame 4 had no pose
    flags = {0: [], 1: ["score drop"], 2: [], 3: ["uncertain"], 5: []}
    res = SimpleNamespace(results={("talus", f): SimpleNamespace(flags=v) for f, v in flags.items()})
    out = _over_bound(res, "talus", E, frames, bound)
    assert out["frames"] == [1, 2]
    assert out["silent"] == 1 and out["silent_frames"] == [2]
    assert out["false_flags"] == 1
