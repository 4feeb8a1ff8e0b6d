"""Defaults of tracking a study (core.tracking.from_study): the bone DRRs render a bone's
attenuation in excess of the soft tissue around it, and flatfield-corrected frames of several
bones are tracked jointly (each bone with its neighbours' DRRs subtracted), and tracked sequentially
they are searched with their neighbours subtracted (``sequential_subtract`` auto)."""

from __future__ import annotations

import numpy as np
import pytest

from core.render import HUTransfer
from core.study import Study
from core.tracking import from_study
from core.tracking.from_study import tissue_excess_transfer, track_study


def test_tissue_excess_transfer_is_the_bone_over_soft_tissue():
    from core.synthetic.scene import excess_transfer

    hu = np.linspace(-1000.0, 3000.0, 4001)
    mine = tissue_excess_transfer(200.0)(hu)
    # what a bone adds to the generator's radiographs: mu(HU) - mu(40 HU), clipped at 0
    truth = excess_transfer(HUTransfer())(hu)
    above = hu >= 200.0
    np.testing.assert_allclose(mine[above], truth[above], rtol=1e-5, atol=1e-7)
    assert np.all(mine[~above] == 0.0)
    # the step at the threshold is small against the cortex: trabecular voxels crossing it do not flicker
    step = float(tissue_excess_transfer(200.0)(np.array([200.0]))[0])
    cortex = float(tissue_excess_transfer(200.0)(np.array([1500.0]))[0])
    assert step < 0.15 * cortex
    plain = HUTransfer(threshold=200.0)
    assert float(plain(np.array([200.0]))[0]) > 0.45 * float(plain(np.array([1500.0]))[0])  # the old default


@pytest.fixture(scope="module")
def demo(demo_walk_48, tmp_path_factory):
    """A copy of the shared demo study (the tests write reports into it)."""
    import shutil

    return shutil.copytree(demo_walk_48, tmp_path_factory.mktemp("defaults") / "demo")


def _captured(monkeypatch):
    import types

    import core.render

    seen = {}

    def renderer(rig, volumes, *, transfer=None, device=None, **kw):
        return types.SimpleNamespace(transfer=transfer, volumes=volumes)

    monkeypatch.setattr(core.render, "DRRRenderer", renderer)

    def fake_track(renderer, bones, frames, order, *, options=None, **kw):
        seen["options"], seen["transfer"], seen["bones"] = options, renderer.transfer, [b.name for b in bones]
        seen["models"] = list(bones)
        frames(order[0])  # the reader works
        from core.tracking.trial import TrackingResult

        return TrackingResult(tuple(seen["bones"]), tuple(order), {}, "complete", 0.0)

    monkeypatch.setattr(from_study, "track", fake_track)
    return seen


@pytest.mark.parametrize("corrected", [True, False])
def test_track_study_defaults(demo, monkeypatch, corrected):
    seen = _captured(monkeypatch)
    names = ["tibia", "talus", "calcaneus"]
    corr = [lambda raw: np.clip(np.asarray(raw, np.float32) / 4095.0, 0, 1)] * 2 if corrected else None
    with Study.open(demo, mode="w") as st:
        _, rep = track_study(st, "walk", names, [1], correction=corr, device="cpu")
    assert seen["bones"] == names
    mode = "joint" if corrected else "sequential"
    assert seen["options"].mode == mode
    assert rep["options"]["mode"] == mode
    hu = np.array([100.0, 200.0, 1500.0])
    np.testing.assert_allclose(seen["transfer"](hu), tissue_excess_transfer(200.0)(hu))


@pytest.mark.parametrize("corrected", [True, False])
def test_auto_mode_follows_the_normalisation(demo, monkeypatch, corrected):
    from core.tracking.trial import TrackingOptions

    seen = _captured(monkeypatch)
    corr = [lambda raw: np.clip(np.asarray(raw, np.float32) / 4095.0, 0, 1)] * 2 if corrected else None
    with Study.open(demo, mode="w") as st:
        track_study(st, "walk", ["tibia", "talus"], [1], correction=corr, device="cpu",
                    options=TrackingOptions(mode="auto", confidence=False))
    assert seen["options"].mode == ("joint" if corrected else "sequential")
    assert seen["options"].confidence is False


@pytest.mark.parametrize("subtract", [True, False])
def test_track_study_keeps_given_options(demo, monkeypatch, subtract):
    from core.tracking.trial import TrackingOptions

    seen = _captured(monkeypatch)
    o = TrackingOptions(mode="sequential", confidence=False, sequential_subtract=subtract)
    corr = [lambda raw: np.clip(np.asarray(raw, np.float32) / 4095.0, 0, 1)] * 2
    with Study.open(demo, mode="w") as st:
        _, rep = track_study(st, "walk", ["tibia", "talus"], [1], correction=None if subtract else corr,
                             options=o, device="cpu", transfer=HUTransfer(threshold=150.0))
    assert seen["options"] is o  # an explicit choice wins over what the frames say
    assert rep["options"]["sequential_subtract"] is subtract
    assert seen["transfer"] == HUTransfer(threshold=150.0)


@pytest.mark.parametrize(("mode", "corrected"), [("sequential", True), ("sequential", False),
                                                  ("auto", False), ("auto", True), ("joint", False)])
def test_sequential_subtract_auto_follows_the_normalisation(demo, monkeypatch, mode, corrected):
    """``sequential_subtract`` None (the default): on for sequential tracking of flatfield-corrected
    frames, off for frames divided by the full scale; joint tracking's options are left as they are."""
    from core.tracking.trial import TrackingOptions

    seen = _captured(monkeypatch)
    o = TrackingOptions(mode=mode, confidence=False)
    assert o.sequential_subtract is None
    corr = [lambda raw: np.clip(np.asarray(raw, np.float32) / 4095.0, 0, 1)] * 2 if corrected else None
    with Study.open(demo, mode="w") as st:
        _, rep = track_study(st, "walk", ["tibia", "talus"], [1], correction=corr, options=o, device="cpu")
    got = seen["options"]
    if got.mode == "joint":  # auto on corrected frames, or joint as given: untouched
        assert (mode, corrected) in (("auto", True), ("joint", False))
        assert got.sequential_subtract is None and "sequential_subtract" not in rep["options"]
        return
    assert got.sequential_subtract is corrected
    assert rep["options"]["sequential_subtract"] is corrected
    assert got.confidence is False and got.guess == o.guess  # the rest as given


def test_track_study_isolates_the_bones_for_a_transfer_without_threshold(demo, monkeypatch):
    from scipy import ndimage

    seen = _captured(monkeypatch)
    corr = [lambda raw: np.clip(np.asarray(raw, np.float32) / 4095.0, 0, 1)] * 2
    with Study.open(demo, mode="w") as st:
        track_study(st, "walk", ["talus"], [1], correction=corr, device="cpu")
        plain = seen["models"][0]
        track_study(st, "walk", ["talus"], [1], correction=corr, device="cpu", transfer=HUTransfer())
        iso = seen["models"][0]
    np.testing.assert_array_equal(iso.mask, plain.mask)
    np.testing.assert_allclose(iso.centroid, plain.centroid)
    rim = max(from_study.ISOLATE_MM, float(plain.volume.spacing.max()))  # at least one voxel
    far = ndimage.distance_transform_edt(~plain.mask, sampling=plain.volume.spacing[::-1]) > rim + 1e-6
    assert far.any() and np.all(iso.volume.data[far] == -1000)  # soft tissue around the bone: air
    assert np.any(plain.volume.data[far] > -1000)  # with the thresholded default it stays as it is
    np.testing.assert_array_equal(iso.volume.data[plain.mask], plain.volume.data[plain.mask])
