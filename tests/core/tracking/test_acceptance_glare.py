"""The acceptance trial's frames with the veiling glare measured from calibration disc frames and
undone (core.studies.tracking.acceptance.TrackingScene(glare=True)), as a lab's correction does."""

import numpy as np

from core.studies.tracking import acceptance


def test_scene_measures_the_glare_and_undoes_it():
    ts = acceptance.TrackingScene(n_frames=2, pixels=96, spacing=1.5, device="cpu", glare=True)
    assert len(ts.glare) == 2
    for g, m in zip(ts.glare, ts.scene.imaging, strict=True):  # the generator's values: test only
        assert abs(g.fraction - m.glare_fraction) < 0.1 * m.glare_fraction
        assert abs(g.sigma_px - m.glare_sigma_px) < 0.1 * m.glare_sigma_px
    undone = ts.frames(1)
    ts.glare, ts._cache = [], {}  # the same frame as it comes, glare kept
    for a, b in zip(undone, ts.frames(1), strict=True):
        assert a.shape == b.shape and np.all(np.isfinite(a))
        dark = b < np.percentile(b[b > 0], 10)  # glare lifts the darkest pixels most
        assert np.mean(a[dark]) < np.mean(b[dark])
