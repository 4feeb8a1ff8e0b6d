"""likelihood_weights.ROBUST_GRAPHS' bookkeeping, the graph path forced on Warp's CPU device (which
records a capture and replays it, or refuses it): the first call launches one by one, the second records
(or falls back to one by one), later ones replay with the fit's coefficients written anew; the stage's
poses and scores the same to the bit as without the path (ideal 128² talus, four frames registered with
the stage, so that the recorded graphs are replayed)."""

from __future__ import annotations

import numpy as np


def test_robust_graph_path_falls_back_to_the_same_values(talus_scene, monkeypatch):
    import core.tracking.likelihood_weights as lw
    from core.tracking.cost import prepare_frame
    from core.tracking.register import RegistrationOptions, register

    sc, m, r = talus_scene["scene"], talus_scene["model"], talus_scene["renderer"]
    o = RegistrationOptions(bounds=(3.0, 3.0), search="newton", final="likelihood", final_highpass_px=2.0)
    frames = [prepare_frame(talus_scene["fluence"](i)) for i in (1, 2, 3, 4)]
    import warp as wp

    replayed = []
    plain = wp.capture_launch
    monkeypatch.setattr(wp, "capture_launch", lambda g, *a, **k: (replayed.append(1), plain(g, *a, **k))[1])
    out = {}
    for forced in (False, True):
        monkeypatch.setattr(lw._RegionWeights, "_robust_graphs_apply", lambda self, f=forced: f)
        out[forced] = [register(r, f, bone=0, initial_pose=sc.poses(i)[0], center=m.centroid, options=o)
                       for i, f in zip((1, 2, 3, 4), frames, strict=True)]
    from core.tracking.engine_likelihood import _CACHE

    states = [v for e in _CACHE[r].values() for v in e.__dict__.get("_robust_graphs", {}).values()]
    assert states and all(x in ("seen", "never") or len(x) == 2 for x in states)
    assert (any(not isinstance(x, str) for x in states) and len(replayed) >= 4) or "never" in states
    for a, b in zip(out[False], out[True], strict=True):
        assert a.timing["likelihood_taken"] == b.timing["likelihood_taken"] == 1
        np.testing.assert_array_equal(a.pose, b.pose)
        assert a.score == b.score
