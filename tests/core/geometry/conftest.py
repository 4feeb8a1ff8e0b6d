"""Ground-truth biplane rigs for the geometry tests (foot/ankle-like set-ups), as fixtures.

The suite runs with ``--import-mode=importlib``, so helpers are handed to tests as fixtures
(``make_rig``, ``look_at``, ``volume_points``, ``rig_iso``) rather than imported.

Sources 1.3-1.5 m from the isocentre, 1024 x 1024 detectors with ~0.3 mm pixels placed
0.2-0.4 m beyond the isocentre, principal rays 60-120 degrees apart, principal points within
20 px of the image centre and slightly different fx, fy. The lab origin (the calibration object's)
is a few cm away from the isocentre.
"""

from __future__ import annotations

import numpy as np
import pytest

from core.geometry import Camera, Rig, make_K


def _unit(v):
    return v / np.linalg.norm(v)


def look_at_camera(source, target, *, roll, fx, fy, cu, cv, size=1024, pixel_size=0.3, name=""):
    """Camera at ``source`` whose principal ray passes through ``target``, rotated by ``roll``."""
    z = _unit(np.asarray(target, float) - source)
    helper = np.array([0.0, 0.0, 1.0]) if abs(z[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    x0 = _unit(np.cross(helper, z))
    y0 = np.cross(z, x0)
    x = np.cos(roll) * x0 + np.sin(roll) * y0
    y = np.cross(z, x)
    R = np.vstack([x, y, z])
    t = -R @ source
    return Camera(make_K(fx, fy, cu, cv), R, t, size, size, pixel_size, name)


def random_rig(seed: int, n_views: int = 2) -> tuple[Rig, np.ndarray]:
    """A random rig and its isocentre (lab, mm)."""
    rng = np.random.default_rng(seed)
    iso = rng.uniform(-50, 50, 3)
    first = _unit(rng.standard_normal(3))
    dirs = [first]
    while len(dirs) < n_views:
        d = _unit(rng.standard_normal(3))
        ang = np.degrees(np.arccos(np.clip(d @ first, -1, 1)))
        if 60 <= ang <= 120 and all(abs(d @ e) < 0.95 for e in dirs):
            dirs.append(d)
    cams = []
    for i, d in enumerate(dirs):
        dist = rng.uniform(1300, 1500)
        sid = dist + rng.uniform(200, 400)
        pix = rng.uniform(0.28, 0.32)
        fx = sid / pix
        fy = fx * (1 + rng.normal(0, 0.003))
        cu, cv = 511.5 + rng.uniform(-20, 20, 2)
        target = iso + rng.normal(0, 5, 3)
        cams.append(
            look_at_camera(
                iso - dist * d,
                target,
                roll=rng.uniform(-np.pi, np.pi),
                fx=fx,
                fy=fy,
                cu=cu,
                cv=cv,
                pixel_size=pix,
                name=f"cam{i + 1:02d}",
            )
        )
    return Rig(tuple(cams)), iso


def volume_points(rng: np.random.Generator, centre, n: int, half: float = 60.0) -> np.ndarray:
    """``n`` points uniform in a cube of half-size ``half`` mm (a foot/ankle volume)."""
    return np.asarray(centre) + rng.uniform(-half, half, (n, 3))


@pytest.fixture
def make_rig():
    """``make_rig(seed, n_views=2) -> (Rig, isocentre)``."""
    return random_rig


@pytest.fixture
def look_at():
    """``look_at(source, target, *, roll, fx, fy, cu, cv, size=1024, pixel_size=0.3, name="")``."""
    return look_at_camera


@pytest.fixture(name="volume_points")
def _volume_points_fixture():
    """``volume_points(rng, centre, n, half=60.0)``: points in a foot/ankle-sized cube."""
    return volume_points


@pytest.fixture(params=[0, 1, 2], ids=lambda s: f"rig{s}")
def rig_iso(request) -> tuple[Rig, np.ndarray]:
    """(Rig, isocentre) for three random biplane set-ups."""
    return random_rig(request.param)
