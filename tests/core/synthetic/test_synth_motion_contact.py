"""Stance trajectories keep the phantoms' touching bones apart (core.synthetic.motion.keep_apart)."""

import numpy as np
import pytest

from core.synthetic import sdf as S
from core.synthetic.motion import CONTACTS, MIN_SPACE_MM, joint_spaces, stance_trajectories
from core.synthetic.phantoms import _extent, bone_spec, voxel_grid
from core.tracking.bones import marching_tetrahedra
from core.tracking.kinematics import min_distance

TRIAL = ("tibia", "talus", "calcaneus")


def _motion_rng(seed: int) -> np.random.Generator:
    """The motion's generator as make_foot_scene draws it from the scene seed."""
    return np.random.default_rng(np.random.SeedSequence(seed).spawn(4)[1])


def _trial(seed: int, n: int = 100, phase=(0.0, 0.6), **kw) -> np.ndarray:
    return stance_trajectories(n, names=TRIAL, seed=_motion_rng(seed), phase=phase, **kw)


def test_seed0_acceptance_trial_is_unchanged():
    # all stored acceptance results are on seed 0 (100 frames over 0.6 of stance): bit for bit the
    # poses of the generator before it kept bones apart (min_space_mm=None is that generator)
    T = _trial(0)
    np.testing.assert_array_equal(T, _trial(0, min_space_mm=None))
    # values of the generator before the change (this 2-core x86_64 machine)
    np.testing.assert_allclose(T[:, [0, 50, 99], :3, 3].sum(axis=1), _SEED0_TRANSLATIONS, rtol=0, atol=1e-9)
    # its smallest tibia-talus space is positive (0.426 mm on the exact surfaces;
    # 0.144 mm at frame 91 by the acceptance study's voxel-mask measure at 0.5 mm)
    js = joint_spaces(T, TRIAL)
    assert js["tibia-talus"].min() == pytest.approx(0.426, abs=0.01)
    # and so is the whole stance
    np.testing.assert_array_equal(_trial(0, 101, (0.0, 1.0)), _trial(0, 101, (0.0, 1.0), min_space_mm=None))


_SEED0_TRANSLATIONS = np.array([[-121.1824627654135, -1.1172149071425, 17.0661862861547],
                                [-77.7693105983466, 3.3865072539196, 2.1446698860337],
                                [-65.4023962907398, -1.6027915640101, 7.3270772229815]])


def _mesh(name: str, near: str, h: float = 0.75, reach: float = 6.0):
    """Surface mesh (mm, anatomical frame) of ``name``'s exact shape, the triangles within ``reach``
    of ``near``'s surface (at the anatomical pose; the bones move little relative to each other)."""
    sa, sb = bone_spec(name), bone_spec(near)
    lo_a, hi_a = _extent(sa.shape, sa.search, 0.0)
    lo_b, hi_b = _extent(sb.shape, sb.search, reach + 2.0)
    origin, pts, _ = voxel_grid(np.maximum(lo_a, lo_b), np.minimum(hi_a, hi_b), h)
    V, F = marching_tetrahedra(-S.sample_sdf(sa.shape, pts))
    V = origin + V * h
    F = F[np.all(S.sample_sdf(sb.shape, V)[F] < reach, axis=1)]
    used = np.unique(F)
    remap = np.full(len(V), -1)
    remap[used] = np.arange(len(used))
    return V[used], remap[F]


@pytest.fixture(scope="module")
def meshes():
    return {(a, b): (_mesh(a, b), _mesh(b, a)) for a, b in CONTACTS}


def test_no_pair_interpenetrates_over_seeds(meshes):
    n, changed = 41, []
    # the mesh distances of every seed's frames are measured in one call per pair (each call sets
    # up the meshes' triangle lists again)
    worst_kept = {pair: [] for pair in CONTACTS}  # (seed, pose a, pose b, exact space)
    crossed_free = {pair: [] for pair in CONTACTS}  # (seed, pose a, pose b)
    for seed in range(10):
        free = _trial(seed, n, (0.0, 1.0), min_space_mm=None)
        kept = _trial(seed, n, (0.0, 1.0))
        if not np.array_equal(free, kept):
            changed.append(seed)
        js_free, js = joint_spaces(free, TRIAL), joint_spaces(kept, TRIAL)
        for (a, b), key in zip(CONTACTS, js, strict=True):
            # exact surfaces: at least the minimum at the 101 fractions it is kept at, and never
            # below zero between them
            assert js[key].min() > 0.0, (seed, key)
            on_grid = js[key][::2]  # frames 0, 2, ... of 41 lie on keep_apart's 101 fractions
            assert on_grid.min() >= MIN_SPACE_MM - 0.002 - 1e-6, (seed, key, on_grid.min())
            ok = js_free[key] >= MIN_SPACE_MM
            np.testing.assert_array_equal(kept[TRIAL.index(a), ok & (js_free[key] > 1.0)],
                                          free[TRIAL.index(a), ok & (js_free[key] > 1.0)])
            # the mesh distance (core.tracking.kinematics) is checked where the bones come closest
            worst = np.argsort(js_free[key])[:2]
            ia, ib = TRIAL.index(a), TRIAL.index(b)
            worst_kept[a, b] += [(seed, kept[ia, w], kept[ib, w], js[key][w]) for w in worst]
            if js_free[key].min() < -0.5:  # an interpenetrating pair: the surfaces cross
                k = int(np.argmin(js_free[key]))
                crossed_free[a, b].append((seed, free[ia, k], free[ib, k]))
    for pair in CONTACTS:
        seeds, pa, pb, exact = zip(*worst_kept[pair], strict=True)
        d = min_distance(*meshes[pair], np.array(pa), np.array(pb))["distance"]
        # the mesh distance agrees: the kept bones are apart
        assert np.all(d > 0.0), (pair, list(zip(seeds, d, strict=True)))
        # (the mesh, 0.75 mm, is no closer than the exact surfaces: it can miss the phantom
        # tibia's thin lateral lip beside the talus, which the exact measure keeps)
        low = d < np.array(exact) - 0.03
        assert not low.any(), (pair, np.array(seeds)[low], d[low], np.array(exact)[low])
        if crossed_free[pair]:
            seeds, pa, pb = zip(*crossed_free[pair], strict=True)
            d0 = min_distance(*meshes[pair], np.array(pa), np.array(pb))["distance"]
            assert np.all(d0 < 0.05), (pair, seeds, d0)
    # the seeds whose motion the fix changed (over the whole stance), seed 0 not among them
    assert changed == [1, 3, 4, 6, 7, 9]


def test_correction_is_smooth_and_independent_of_sampling():
    a = _trial(4, 100, (0.0, 0.6))
    b = _trial(4, 34, (0.0, 0.6))  # every third frame of the same stance fractions
    np.testing.assert_allclose(b, a[:, ::3], rtol=0, atol=1e-9)
    # another part of the stance: the same poses at the same fractions (the correction is measured
    # over the whole stance whatever the phase)
    whole = _trial(4, 101, (0.0, 1.0))
    np.testing.assert_allclose(_trial(4, 51, (0.5, 1.0)), whole[:, 50:], rtol=0, atol=1e-9)
    np.testing.assert_allclose(_trial(4, 21, (0.1, 0.3)), whole[:, 10:31], rtol=0, atol=1e-9)
    n = 301
    d = _trial(4, n, (0.0, 1.0))[0, :, :3, 3] - _trial(4, n, (0.0, 1.0), min_space_mm=None)[0, :, :3, 3]
    assert 1.5 < np.linalg.norm(d, axis=1).max() < 2.5  # the tibia lifted off the talus, mm
    dt = 0.6 / (n - 1)  # s: a 0.6 s stance
    acc = np.linalg.norm(np.diff(d, 2, axis=0), axis=1) / 1000.0 / dt**2
    assert acc.max() < 10.0  # m/s^2, on top of the motion's own (< 40)


def test_bones_with_their_own_shapes_are_left_alone():
    # the harder trial gives its bones' centroids (its own shapes): no correction from the phantoms
    cents = {n: np.zeros(3) + i for i, n in enumerate(TRIAL)}
    np.testing.assert_array_equal(_trial(4, 20, centroids=cents),
                                  _trial(4, 20, centroids=cents, min_space_mm=None))
    sub = stance_trajectories(20, names=["tibia"], seed=_motion_rng(4), phase=(0.0, 0.6))
    np.testing.assert_array_equal(sub, stance_trajectories(20, names=["tibia"], seed=_motion_rng(4),
                                                           phase=(0.0, 0.6), min_space_mm=None))


def test_both_pairs_kept_apart_at_once():
    # twice the trial's jitter: seed 4 drives the tibia and the calcaneus into the talus (free
    # spaces -1.41 and -1.21 mm); both are moved off it, the talus is not, rotations stay
    kw = dict(names=TRIAL, seed=4, phase=(0.0, 1.0), jitter_mm=2.0)
    kept = stance_trajectories(61, **kw)
    free = stance_trajectories(61, min_space_mm=None, **kw)
    js_free, js = joint_spaces(free, TRIAL), joint_spaces(kept, TRIAL)
    assert js_free["tibia-talus"].min() < -1.0 and js_free["calcaneus-talus"].min() < -1.0
    np.testing.assert_array_equal(kept[:, :, :3, :3], free[:, :, :3, :3])
    np.testing.assert_array_equal(kept[1], free[1])  # the talus
    moved = np.linalg.norm(kept[:, :, :3, 3] - free[:, :, :3, 3], axis=2).max(axis=1)
    assert moved[0] > 1.0 and moved[2] > 1.0
    for key in ("tibia-talus", "calcaneus-talus"):
        assert js[key].min() > 0.0, key
        assert js[key][::3].min() >= MIN_SPACE_MM - 0.002 - 1e-6, key  # frames on the 101 fractions
