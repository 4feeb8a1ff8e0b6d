"""core.studies.tracking.smoother: its measures and the heel-strike-like jerk it adds to the truth."""

import numpy as np

from core.geometry.transforms import params_from_pose
from core.studies.tracking import smoother as st


def test_measures_count_frames_over_4x_and_the_silent_ones():
    bound = {"rms_mm": 0.01, "rms_deg": 0.1}
    E = np.zeros((10, 6))
    E[:, 0] = 0.01
    E[3, 0] = 0.05  # over 4x in mm, flagged
    E[7, 4] = 0.5  # over 4x in degrees, not flagged
    E[9] = np.nan  # no pose: left out
    fl = np.zeros(10, bool)
    fl[3] = True
    m = st.measures(E, bound, fl, sigma=np.full((10, 6), 0.02))
    assert m["frames"] == 9 and m["over_4x"] == [3, 7] and m["silent_over_4x"] == [7]
    assert m["max"] == [0.05, 0.5]
    assert abs(m["rms_over_bound"][0] - np.sqrt((8 * 0.01 ** 2 + 0.05 ** 2) / 9) / 0.01) < 1e-3
    assert m["within_2_sigma"] == [0.963, 0.963]  # one of 27 axes out in each group


def test_the_jerk_steps_every_coordinate_after_its_frame():
    y = st._step(100, st.T0)
    assert np.all(y[:st.T0 + 1] == 0) and abs(y[-1] - 1) < 1e-6 and y.max() > 1.05  # damped: overshoots
    assert y[st.T0 + 3] > 0.9  # within ~10 ms at the trial's 278 Hz
    T = np.tile(np.eye(4), (100, 1, 1))
    c = np.array([1.0, 2.0, 3.0])
    Tj = st.transient(T, c, 0.5)
    d = np.array([params_from_pose(a, center=c, base=b) for a, b in zip(Tj, T, strict=True)])
    np.testing.assert_allclose(d[:, :3], 0.5 * y[:, None] * np.ones(3), atol=1e-12)
    np.testing.assert_allclose(np.degrees(d[:, 3:]), 0.5 * y[:, None] * np.ones(3), atol=1e-9)
