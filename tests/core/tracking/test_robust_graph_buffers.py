"""likelihood_weights.ROBUST_GRAPHS: a recorded graph replays only on the very buffers it was recorded
with. An engine keeps its buffers per region size (the last few sizes); a size met again after its set
was dropped gets new buffers, and a graph keyed by some of them only would replay on freed memory. Here
one buffer at a time is made anew under the engine (the graph path forced on Warp's CPU device, which
records and replays): the next call is not a replay, and it gives the factors of the path without graphs."""

from __future__ import annotations

import numpy as np


def test_a_robust_graph_is_not_replayed_on_other_buffers(talus_scene, monkeypatch):
    import warp as wp

    import core.tracking.likelihood_weights as lw
    from core.tracking.cost import prepare_frame
    from core.tracking.register import RegistrationOptions, register

    sc, m, r = talus_scene["scene"], talus_scene["model"], talus_scene["renderer"]
    monkeypatch.setattr(lw._RegionWeights, "_robust_graphs_apply", lambda self: True)
    last = []
    plain = lw._RegionWeights._robust_graphed

    def spy(self, s, k, sigma_px, kind):
        last[:] = [self, s, k, sigma_px, kind]
        return plain(self, s, k, sigma_px, kind)

    monkeypatch.setattr(lw._RegionWeights, "_robust_graphed", spy)
    o = RegistrationOptions(bounds=(3.0, 3.0), search="newton", final="likelihood", final_highpass_px=2.0)
    register(r, prepare_frame(talus_scene["fluence"](1)), bone=0, initial_pose=sc.poses(1)[0],
             center=m.centroid, options=o)
    eng, s, k, sigma_px, kind = last
    replays = []
    launch = wp.capture_launch
    monkeypatch.setattr(wp, "capture_launch", lambda g, *a, **kw: (replays.append(1), launch(g, *a, **kw))[1])

    def factors(graphs: bool) -> np.ndarray:
        monkeypatch.setattr(lw._RegionWeights, "_robust_graphs_apply", lambda self: graphs)
        return eng.robust_weights(s, k, sigma_px=sigma_px, kind=kind).numpy().copy()

    want = factors(False)
    for name in ("rf_a", "rf_local", "rf_scale", "jt"):  # a blur's, the local RMS's, the scale's, unused's
        for _ in range(3):  # recorded (if not yet), then replayed
            np.testing.assert_array_equal(factors(True), want)
        assert replays  # (the graphs replay on these buffers)
        old = eng._bufs[name]
        eng._bufs[name] = wp.zeros(old.shape, dtype=old.dtype, device=old.device)  # made anew
        replays.clear()
        np.testing.assert_array_equal(factors(True), want)
        assert not replays, name  # not the graph recorded on the buffer before
        del old
