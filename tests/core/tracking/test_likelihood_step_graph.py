"""The likelihood final stage's recorded steps (core.tracking.likelihood_graph, engine_likelihood.
STEP_GRAPH): the item table computed on the device, the step's launches recorded once — the same
poses, confidences, steps and evaluations as the plain steps' (CPU device, ideal 128² views of the
talus and calcaneus, their stages side by side)."""

from __future__ import annotations

import numpy as np

from core.geometry.transforms import pose_from_params
from tests.core.tracking.stage_helpers import engine_at, stage_calls


def test_recorded_steps_are_the_plain_steps(talus_calcaneus_128, monkeypatch):
    import core.tracking.engine_likelihood as el
    from core.tracking.final_stage import final_stages

    r, frame, calls, of = stage_calls(talus_calcaneus_128)
    out = {}
    for on in (False, True, False):  # (and the plain steps again after the recorded ones: same engines)
        monkeypatch.setattr(el, "STEP_GRAPH", on)
        out.setdefault(on, []).append(final_stages(r, frame, calls))
    for a, b, c in zip(out[False][0], out[True][0], out[False][1], strict=True):
        assert a.timing["likelihood_taken"] == b.timing["likelihood_taken"] == 1
        assert a.timing["likelihood_steps"] == b.timing["likelihood_steps"] > 0
        assert a.timing["likelihood_renders"] == b.timing["likelihood_renders"]
        assert a.evaluations == b.evaluations
        for x in (b, c):
            np.testing.assert_array_equal(a.pose, x.pose)
            np.testing.assert_array_equal(a.fit.covariance, x.fit.covariance)
    eng = el.likelihood_engine(r, bone=0, views=(0, 1), highpass_px=2.0, lag_px=of.final_lag_px,
                               others_gain=of.final_others_gain)
    assert eng._graphs and all(w.graph is None for w in eng._graphs.values())  # (the CPU: no capture)


def test_moments_triangle_is_the_full_table(talus_scene, monkeypatch):
    """The table summed on and above its diagonal (engine_likelihood.MOMENTS_TRI), mirrored on the
    host: the full table's entries to the bit (the same sums), with and without the design's
    differences."""
    import core.tracking.engine_likelihood as el
    from core.tracking.cost import prepare_frame, search_roi

    sc, model, r = talus_scene["scene"], talus_scene["model"], talus_scene["renderer"]
    start = pose_from_params(np.r_[0.3, 0, 0, 0, np.radians(0.4), 0], center=model.centroid,
                             base=sc.poses(2)[0])
    fr = prepare_frame(talus_scene["fluence"](2), valid_range=None)
    roi = search_roi(r, start, 0, views=[0, 1], center=model.centroid, reach_mm=2.0)
    eng = el.LikelihoodEngine(r, bone=0, views=(0, 1), highpass_px=2.0)
    eng.set_frame(fr, base_pose=start, center=model.centroid, roi=roi)
    x, h = np.array([0.05, -0.1, 0.0, 0.1, 0.0, -0.05]), np.full(6, 0.05)
    for diff in (True, False):
        monkeypatch.setattr(el, "DIFF_IMAGES", diff)
        tables = []
        for tri in (False, True):
            monkeypatch.setattr(el, "MOMENTS_TRI", tri)
            s = eng.step(x, h)
            tables.append(s["M"])
            assert eng._tri == tri
        np.testing.assert_array_equal(tables[0], tables[1])


def test_chi2_share_counts_the_weighed_pixels(talus_scene):
    """N of χ²/N (engine's n_pixels: the steps' stop and the independent-pixel covariance) counts the
    pixels with a positive weight once a factor weighs some 0 (a support mask; the rim band), back to
    the usable pixels when the weights are reset."""
    eng = engine_at(talus_scene)
    h = np.full(6, 0.05)
    eng.step(np.zeros(6), h)
    usable = eng.n_pixels
    assert usable == int((eng._w.numpy() > 0).sum())
    mask = np.ones((2, *eng._cap), np.float32)
    mask[:, ::2] = 0.0  # (every other row)
    eng.scale_weights(mask)
    s = eng.step(np.zeros(6), h, reuse=True)
    assert eng.n_pixels == int((eng._w.numpy() > 0).sum()) < usable
    out = eng.refine(iters=1, sandwich=False, reuse=True)
    np.testing.assert_allclose(out["covariance_independent"],
                               np.linalg.inv(s["JJ"]) * s["chi2"] / eng.n_pixels)
    eng.reset_weights()
    eng.step(np.zeros(6), h, reuse=True)
    assert eng.n_pixels == usable
