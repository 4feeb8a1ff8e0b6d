"""Bone contact: signed surface distance between bones and the interpenetration penalty."""

from __future__ import annotations

import numpy as np
import pytest

from core.render.volume import CTVolume
from core.tracking.bones import bone_model
from core.tracking.contact import ContactModel, penetration_depths, penetration_penalty, surface_gap


def _ball(radius: float, name: str, hollow: bool = False) -> ContactModel:
    n = int(2 * radius + 12)
    ax = (np.arange(n) - (n - 1) / 2) * 1.0
    z, y, x = np.meshgrid(ax, ax, ax, indexing="ij")
    r = np.sqrt(x**2 + y**2 + z**2)
    data = np.where(r <= radius, 1000, 0).astype(np.int16)
    if hollow:  # marrow below the threshold inside a 2 mm shell: still bone for contact
        data[r < radius - 2] = 100
    vol = CTVolume(data, spacing=(1.0, 1.0, 1.0), origin=(-(n - 1) / 2,) * 3, units="HU", name=name)
    return ContactModel.from_bone(bone_model(vol, name=name, mesh=False, margin_mm=4.0))


def _at(x: float) -> np.ndarray:
    T = np.eye(4)
    T[0, 3] = x
    return T


@pytest.mark.parametrize("hollow", [False, True])
def test_surface_gap_of_two_balls(hollow):
    a, b = _ball(10, "a", hollow), _ball(8, "b", hollow)
    for sep, gap in ((21.0, 3.0), (19.0, 1.0), (16.0, -2.0)):
        g = surface_gap(a, np.eye(4), b, _at(sep))
        assert g == pytest.approx(gap, abs=0.6), (sep, g)


def test_penetration_is_zero_apart_and_grows_with_depth():
    a, b = _ball(10, "a"), _ball(8, "b")
    poses = np.stack([_at(x) for x in (-4.0, 0.0, 4.0, 6.0)])  # a's poses; b at 21 mm
    d = penetration_depths(a, poses, [(b, _at(21.0))], margin=0.0)
    assert d[0] == 0 and d[1] == 0
    assert 0 < d[2] < d[3]
    assert 0.2 < d[2] < 1.0  # 1 mm deep at the contact point (RMS of the deepest 5 % of points)
    p = penetration_penalty(a, poses, [(b, _at(21.0))], weight=0.05)
    assert np.allclose(p, 0.05 * d**2)
    # a margin keeps bones that far apart: 3 mm apart is too close with a 4 mm margin
    m = penetration_depths(a, poses[1:2], [(b, _at(21.0))], margin=4.0)
    assert m[0] > 0
