"""Shared fixtures of the tracking tests: small synthetic biplane scenes on Warp's CPU device."""

from __future__ import annotations

import numpy as np
import pytest


def _fluence(scene, i):
    frames = scene.render_frame(i)
    out = []
    for m, f in zip(scene.imaging, frames, strict=True):
        img = m.to_float(f)
        out.append(img if m.distortion is None else m.distortion.unwarp(img))
    return out


@pytest.fixture(scope="session")
def talus_scene():
    """Ideal (noise-free, undistorted) 128² views of the talus alone, 1.5 mm voxels, 6 frames,
    with its bone model and a CPU renderer."""
    from core.render import DRRRenderer
    from core.synthetic import make_foot_scene
    from core.tracking.bones import bone_model

    sc = make_foot_scene(n_frames=6, pixels=128, spacing=1.5, names=("talus",), beads_per_bone=0,
                         soft_tissue=False, imaging="ideal", floor_thickness_mm=0)
    model = bone_model(sc.bones[0], mesh=False)
    r = DRRRenderer(sc.rig, [sc.bones[0].to_attenuation(sc.bone_transfer)], device="cpu")
    return {"scene": sc, "model": model, "renderer": r, "fluence": lambda i: _fluence(sc, i)}


@pytest.fixture(scope="session")
def talus_calcaneus_128():
    """``(scene, models, renderer, frames)``: ideal 128² views of the talus and calcaneus, 1.5 mm
    voxels, frames 0 and 1 (fluence images, ``frames[i]``), bone models and a CPU renderer."""
    from core.render import DRRRenderer
    from core.synthetic import make_foot_scene
    from core.tracking.bones import bone_model

    sc = make_foot_scene(n_frames=2, pixels=128, spacing=1.5, names=("talus", "calcaneus"), beads_per_bone=0,
                         phase=(0.0, 0.03), soft_tissue=False, imaging="ideal", floor_thickness_mm=0)
    models = [bone_model(b, mesh=False) for b in sc.bones]
    r = DRRRenderer(sc.rig, [b.to_attenuation(sc.bone_transfer) for b in sc.bones], device="cpu")
    frames = {i: [m.to_float(f) for m, f in zip(sc.imaging, sc.render_frame(i), strict=True)] for i in (0, 1)}
    return sc, models, r, frames


@pytest.fixture(scope="session")
def demo_walk_48(tmp_path_factory):
    """A demo study built once per process (read it, or copy it before writing): the 30-frame walk
    in 48² views, 3 mm bone and 6 mm tissue voxels, no calibration session; every bone has its true
    pose at frame 0 as a keyframe (:func:`tests.core.tracking.demo_walk.built`, which the app's
    batch tests share)."""
    from tests.core.tracking.demo_walk import built

    return built(tmp_path_factory)


@pytest.fixture(scope="session")
def keyed(tmp_path_factory):
    """The demo walk whose talus has one hand-set keyframe, frame 12 (frame 0's cleared): two
    ranges, 12 back to 0 and 12 on to 29, both tracking frame 12 (copy it before writing)."""
    from tests.core.tracking.demo_walk import copy_keyed

    return copy_keyed(tmp_path_factory, tmp_path_factory.mktemp("keyed") / "demo")


@pytest.fixture(scope="session")
def rng():
    return np.random.default_rng(1234)


def _walking_talus(pixels: int) -> dict:
    from core.render import DRRRenderer
    from core.synthetic import make_foot_scene
    from core.tracking.bones import bone_model

    sc = make_foot_scene(n_frames=60, pixels=pixels, spacing=1.5, names=("talus",), beads_per_bone=0,
                         soft_tissue=False, imaging="ideal", floor_thickness_mm=0)
    model = bone_model(sc.bones[0], mesh=False)
    r = DRRRenderer(sc.rig, [sc.bones[0].to_attenuation(sc.bone_transfer)], device="cpu")
    cache = {}

    def frames(i):
        if i not in cache:
            cache[i] = _fluence(sc, i)
        return cache[i]

    return {"scene": sc, "model": model, "renderer": r, "frames": frames}


@pytest.fixture(scope="session")
def walking_talus():
    """The talus over 60 frames of stance (≈0.1–2.6 mm per frame early on), ideal 128² views."""
    return _walking_talus(128)


@pytest.fixture(scope="session")
def walking_talus_64():
    """The same walk in ideal 64² views: for tests of the tracking loop's plumbing (journal,
    resume, cancel, review flags), where a registration costs about 2.3x less CPU than at 128²."""
    return _walking_talus(64)


@pytest.fixture
def prefetch_used(monkeypatch):
    """Whether each likelihood stage's set-up took prefetched fluence rows
    (``likelihood_frames._FrameRegions._prefetched`` spied on): a list, one bool a stage, in order."""
    import core.tracking.likelihood_frames as lf

    plain = lf._FrameRegions._prefetched
    used: list = []

    def spy(self, *a, **k):
        out = plain(self, *a, **k)
        used.append(out is not None)
        return out

    monkeypatch.setattr(lf._FrameRegions, "_prefetched", spy)
    return used
