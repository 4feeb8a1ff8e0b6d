"""The likelihood stage's recorded steps (engine_likelihood.STEP_GRAPH, kept per output size and frame
buffers) replayed on new inputs: a region of another size and back, a region of the same size with
other pixels, a new frame's images and base pose, the neighbours' set changing — every step the plain
step's to the bit (CPU device, ideal 128² talus and calcaneus)."""

from __future__ import annotations

import numpy as np

from core.tracking.cost import prepare_frame, search_roi


def _steps(r, sc, models, frames, graph: bool, per_size: bool, monkeypatch) -> tuple:
    import core.tracking.engine_likelihood as el
    import core.tracking.likelihood_launches as LL

    monkeypatch.setattr(el, "STEP_GRAPH", graph)
    monkeypatch.setattr(LL, "BUFFERS_PER_SIZE", per_size)
    eng = el.LikelihoodEngine(r, bone=0, views=(0, 1), highpass_px=2.0)
    c = models[0].centroid
    prep = {i: prepare_frame(frames[i]) for i in (0, 1)}
    P = {i: sc.poses(i) for i in (0, 1)}
    box = search_roi(r, P[0][0], 0, views=(0, 1), center=c, reach_mm=1.0, margin_px=4)
    moved = box + np.array([[-6, 5, 0, 0], [5, -6, 0, 0]])  # (the same size, other pixels)
    small = box + np.array([8, 8, -16, -16])  # (another output size)
    runs = [(0, box, True), (0, small, True), (1, moved, True), (1, box, False), (0, box, True)]
    out = []
    for i, roi, others in runs:
        eng.set_frame(prep[i], base_pose=P[i][0], center=c, roi=roi,
                      others=(P[i][[1]], [1]) if others else None)
        for x in (np.full(6, 0.01), np.full(6, -0.02)):
            out.append(eng.step(x, np.full(6, 0.05)))
    return out, eng


def test_recorded_steps_on_new_inputs(talus_calcaneus_128, monkeypatch):
    sc, models, r, frames = talus_calcaneus_128
    plain, _ = _steps(r, sc, models, frames, False, True, monkeypatch)
    for per_size in (True, False):
        rec, eng = _steps(r, sc, models, frames, True, per_size, monkeypatch)
        assert eng._graphs and len(eng._graphs) <= 4
        for a, b in zip(plain, rec, strict=True):
            for k in ("JJ", "Jr", "chi2", "M"):
                np.testing.assert_array_equal(a[k], b[k])
