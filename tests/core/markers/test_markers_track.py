"""2-D tracking: constant-velocity prediction, lost beads, gap filling."""

import numpy as np
import pytest

from core.markers import FILLED, LOST, TRACKED, track_beads


def _sequence(n=12, hidden=(), seed=0):
    """Two Gaussian beads moving on curved paths (px), a frame stack and the true positions."""
    g = np.random.default_rng(seed)
    t = np.arange(n, dtype=float)
    truth = np.stack([np.stack([30 + 2.5 * t, 40 + 0.08 * t**2], 1),
                      np.stack([90 - 1.5 * t, 30 + 2.0 * t], 1)], axis=1)  # (F, 2, 2)
    yy, xx = np.mgrid[0:100, 0:130].astype(float)
    frames = np.empty((n, 100, 130))
    for f in range(n):
        img = np.full(xx.shape, 0.8)
        for b in range(2):
            if (f, b) in hidden:
                continue
            u, v = truth[f, b]
            img -= 0.5 * np.exp(-((xx - u) ** 2 + (yy - v) ** 2) / (2 * 2.0**2))
        frames[f] = img + g.normal(0, 0.01, img.shape)
    return frames, truth


def test_moving_beads_are_tracked_to_subpixel_precision():
    frames, truth = _sequence()
    tr = track_beads(frames, truth[0] + 1.0, diameter_px=5.0)
    assert np.all(tr.state == TRACKED)
    assert np.abs(tr.uv - truth).max() < 0.1
    # from frame 2 on the constant-velocity prediction is within a pixel
    assert np.abs(tr.predicted[2:] - truth[2:]).max() < 1.0


def test_lost_bead_is_flagged_then_gap_filled_and_reacquired():
    hidden = {(5, 0), (6, 0), (7, 0)}
    frames, truth = _sequence(hidden=hidden)
    tr = track_beads(frames, truth[0], diameter_px=5.0, max_gap=3)
    assert np.all(tr.state[5:8, 0] == FILLED) and np.all(tr.state[8:, 0] == TRACKED)
    assert np.all(tr.status[5:8, 0] != 0)  # the localizer flagged the empty frames
    assert np.abs(tr.uv[5:8, 0] - truth[5:8, 0]).max() < 0.5  # interpolated across the gap
    assert np.isnan(tr.sigma[5:8, 0]).all()
    short = track_beads(frames, truth[0], diameter_px=5.0, max_gap=2)
    assert np.all(short.state[5:8, 0] == LOST) and np.isnan(short.uv[5:8, 0]).all()


def test_gate_rejects_a_jump_to_another_bead():
    frames, truth = _sequence()
    frames[6] = frames[5]  # a repeated frame: the beads did not move as predicted
    tr = track_beads(frames, truth[0], diameter_px=5.0, gate_px=1.0)
    assert tr.state[6].tolist() == [LOST, LOST]


def test_arguments_are_validated():
    frames, truth = _sequence(n=3)
    with pytest.raises(ValueError, match="frames"):
        track_beads(frames[0], truth[0], diameter_px=5.0)
    with pytest.raises(ValueError, match="initial_uv"):
        track_beads(frames, truth[0, :, :1], diameter_px=5.0)
    with pytest.raises(ValueError, match="max_gap"):
        track_beads(frames, truth[0], diameter_px=5.0, max_gap=-1)
