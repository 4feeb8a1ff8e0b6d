"""CPU launches split over threads give the images of one thread, bit for bit."""

import threading

import numpy as np
import pytest
import warp as wp
from scipy.spatial.transform import Rotation

from core.geometry import Camera, make_K
from core.render import CTVolume, DRRRenderer
from core.render.drr import default_cpu_threads, run_parallel


def _camera(angle, pixels=40, f=1500.0):
    ca, sa = np.cos(angle), np.sin(angle)
    R = np.array([[ca, 0.0, -sa], [0.0, 1.0, 0.0], [sa, 0.0, ca]])
    c = (pixels - 1) / 2
    return Camera(make_K(f, f, c + 0.3, c - 0.4), R, [0.0, 0.0, 1000.0], pixels, pixels, pixel_size=0.9)


def _volume(seed, shape=(12, 15, 17)):
    rng = np.random.default_rng(seed)
    data = np.zeros(shape, dtype=np.float32)
    data[2:10, 3:12, 2:14] = rng.random((8, 9, 12)) * 0.04
    D = Rotation.from_rotvec([0.2, -0.1, 0.3]).as_matrix()
    return CTVolume(data, spacing=(0.9, 1.1, 1.3), origin=[-8.0, -9.0, -7.0], direction=D, units="1/mm")


def _poses(B, n_bones, seed=0):
    rng = np.random.default_rng(seed)
    P = np.tile(np.eye(4), (B, n_bones, 1, 1))
    P[..., :3, :3] = Rotation.from_rotvec(rng.normal(0, 0.2, (B * n_bones, 3))).as_matrix().reshape(
        B, n_bones, 3, 3)
    P[..., :3, 3] = rng.normal(0, 2.0, (B, n_bones, 3))
    return P


@pytest.mark.parametrize("interpolation", ["trilinear", "texture"])
@pytest.mark.parametrize("B", [1, 5, 13])
def test_threads_equal_one_thread(interpolation, B):
    cams, vols = [_camera(0.0), _camera(1.2)], [_volume(1), _volume(2)]
    one = DRRRenderer(cams, vols, device="cpu", interpolation=interpolation, cpu_threads=1)
    many = DRRRenderer(cams, vols, device="cpu", interpolation=interpolation, cpu_threads=3)
    P = _poses(B, 2)
    for scale in (1.0, 2.0):
        a = one.render(P, scale=scale)
        b = many.render(P, scale=scale)
        np.testing.assert_array_equal(a.roi, b.roi)
        assert np.array_equal(a.numpy(), b.numpy())
        assert a.numpy().max() > 0
    # one item: nothing to split
    assert np.array_equal(one.render_full(P[0], 1), many.render_full(P[0], 1))


def test_threaded_buffer_is_reused_and_split():
    r = DRRRenderer([_camera(0.0), _camera(1.2)], [_volume(3)], device="cpu", cpu_threads=2)
    P = _poses(13, 1, seed=4)
    first = r.render(P, out_shape=(48, 48))
    ptr = first.images.ptr
    again = r.render(P[::-1].copy(), out_shape=(48, 48))
    assert again.images.ptr == ptr  # the engine's metric pipeline keys on this buffer
    (cached,) = [v for k, v in r._launches.items() if k[0] == 26]
    assert len(cached[4]) == 2
    r.cpu_threads = 1  # changed later: one launch again, same images
    single = r.render(P[::-1].copy(), out_shape=(48, 48)).numpy()
    r2 = DRRRenderer([_camera(0.0), _camera(1.2)], [_volume(3)], device="cpu", cpu_threads=1)
    assert np.array_equal(r2.render(P[::-1].copy(), out_shape=(48, 48)).numpy(), single)


def test_default_threads(monkeypatch):
    monkeypatch.setenv("TALUS_CPU_THREADS", "3")
    assert default_cpu_threads() == 3
    monkeypatch.setenv("TALUS_CPU_THREADS", "0")
    with pytest.raises(ValueError, match="TALUS_CPU_THREADS"):
        default_cpu_threads()
    monkeypatch.delenv("TALUS_CPU_THREADS")
    assert default_cpu_threads() >= 1
    with pytest.raises(ValueError, match="cpu_threads"):
        DRRRenderer([_camera(0.0)], [_volume(0)], device="cpu", cpu_threads=0)


def test_run_parallel_waits_and_raises():
    done = []

    class Cmd:
        def __init__(self, i, fail=False):
            self.i, self.fail = i, fail

        def launch(self):
            done.append((self.i, threading.current_thread().name))
            if self.fail:
                raise RuntimeError(f"launch {self.i}")

    run_parallel([Cmd(0), Cmd(1), Cmd(2)])
    assert sorted(i for i, _ in done) == [0, 1, 2]
    assert done[[i for i, _ in done].index(0)][1] == threading.current_thread().name
    done.clear()
    with pytest.raises(RuntimeError, match="launch 2"):
        run_parallel([Cmd(0), Cmd(1), Cmd(2, fail=True)])
    assert len(done) == 3


def _cuda_available() -> bool:
    wp.init()
    return wp.is_cuda_available()


@pytest.mark.skipif(not _cuda_available(), reason="needs a CUDA device: CUDA launches are never split "
                                                  "over CPU threads")
def test_cuda_untouched():
    r = DRRRenderer([_camera(0.0), _camera(1.2)], [_volume(5)], device="cuda:0", cpu_threads=4)
    r.render(_poses(3, 1))
    assert all(len(v[4]) == 1 for v in r._launches.values())


def _render_in_child(q):
    r = DRRRenderer([_camera(0.0), _camera(1.2)], [_volume(6)], device="cpu", cpu_threads=2)
    q.put(float(r.render(_poses(4, 1, seed=2)).numpy().sum()))


@pytest.mark.skipif(not hasattr(__import__("os"), "fork"), reason="no fork on this platform")
def test_a_forked_child_renders_with_threads_of_its_own():
    import multiprocessing as mp

    r = DRRRenderer([_camera(0.0), _camera(1.2)], [_volume(6)], device="cpu", cpu_threads=2)
    expected = float(r.render(_poses(4, 1, seed=2)).numpy().sum())  # the parent's pool exists
    ctx = mp.get_context("fork")
    q = ctx.Queue()
    p = ctx.Process(target=_render_in_child, args=(q,))
    p.start()
    p.join(timeout=300)
    alive = p.is_alive()
    if alive:
        p.kill()
    assert not alive, "the forked child hung on its parent's thread pool"
    assert p.exitcode == 0 and q.get(timeout=10) == expected
