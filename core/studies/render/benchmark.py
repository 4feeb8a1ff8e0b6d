"""DRR throughput benchmark (``talus bench drr``): prints JSON, asserts nothing.

Cases (DESIGN.md / GPU.md reference on one H100: 0.91 ms and 6 µs per DRR with textures):

* ``ct_1024``: 1024² full-detector DRRs of a 512×512×300 CT (0.5 mm voxels);
* ``bone_roi_300``: 300² ROI DRRs of a 150³ bone sub-volume (0.3 mm voxels: a 45 mm,
  talus-sized box whose projection about fills the ROI), bone-only transfer (HU >= 150).

Each case is timed with one pose × one view per launch and with a batch of poses × two views
per launch (64 poses on CUDA; fewer on the CPU, where Warp runs on one thread — the JSON says how
many). A timed call is the whole :meth:`DRRRenderer.render` (host-side tables, upload, launch)
followed by a device synchronisation, i.e. what an optimizer sees.
"""

from __future__ import annotations

import os
import platform
import time

import numpy as np
import warp as wp

from core.geometry.camera import Camera, Rig, make_K
from core.render.drr import DRRRenderer
from core.render.reference import render_reference
from core.render.volume import CTVolume, HUTransfer

__all__ = ["run_drr_benchmark"]

REFERENCE_H100 = {"ct_1024_single_ms": 0.91, "bone_roi_300_batched_us": 6.0}
TARGET_FACTOR = 1.5
TARGETS_H100 = {"ct_1024_single_ms": 1.4, "bone_roi_300_batched_us": 10.0}  # ~1.5x the reference


def _bench_rig(pixels: int = 1024, pixel_mm: float = 0.3, sid: float = 1400.0) -> Rig:
    """Two cameras 90° apart looking at the origin, source 1 m from it."""
    f = sid / pixel_mm
    c = (pixels - 1) / 2.0
    K = make_K(f, f, c, c)
    cams = []
    for k, ang in enumerate((0.0, np.pi / 2)):
        ca, sa = np.cos(ang), np.sin(ang)
        R = np.array([[ca, 0.0, -sa], [0.0, 1.0, 0.0], [sa, 0.0, ca]])
        t = np.array([0.0, 0.0, 1000.0])
        cams.append(Camera(K, R, t, pixels, pixels, pixel_size=pixel_mm, name=f"cam{k + 1:02d}"))
    return Rig(tuple(cams))


def _phantom(shape_kji: tuple[int, int, int], spacing: float, seed: int) -> CTVolume:
    """CT-like HU volume: soft-tissue ball (40 HU) with a dense core (940 HU) and texture; most
    rays through the box cross tissue, so little can be skipped."""
    rng = np.random.default_rng(seed)
    nz, ny, nx = shape_kji
    z, y, x = np.ogrid[-1 : 1 : nz * 1j, -1 : 1 : ny * 1j, -1 : 1 : nx * 1j]
    r2 = x**2 + y**2 + z**2
    hu = np.where(r2 < 0.9, 40.0, -1000.0) + np.where(r2 < 0.3, 900.0, 0.0)
    hu = hu + rng.normal(0.0, 30.0, size=(1, ny, nx))  # cheap texture, broadcast along k
    data = hu.astype(np.float32)
    origin = -0.5 * spacing * (np.array([nx, ny, nz]) - 1)
    return CTVolume(data, spacing=[spacing] * 3, origin=origin, name=f"phantom{nx}")


def _bone(n: int, spacing: float, seed: int) -> CTVolume:
    """Cropped bone sub-volume: an ellipsoidal bone (1400 HU cortex 2 mm thick around 300 HU
    trabecular bone with texture) in air/soft tissue, filling its box like a cropped talus."""
    rng = np.random.default_rng(seed)
    g = (np.arange(n) - (n - 1) / 2) * spacing
    z, y, x = np.meshgrid(g, g, g, indexing="ij")
    a = np.array([0.47, 0.40, 0.33]) * n * spacing
    r = np.sqrt((x / a[0]) ** 2 + (y / a[1]) ** 2 + (z / a[2]) ** 2)
    depth = (1 - r) * a.min()  # approx. distance inside the surface, mm
    hu = np.where(r < 1, np.where(depth < 2.0, 1400.0, 300.0), 20.0)
    hu = hu + rng.normal(0.0, 60.0, size=hu.shape) * (r < 1)
    origin = -np.full(3, (n - 1) / 2 * spacing)
    return CTVolume(hu.astype(np.float32), spacing=[spacing] * 3, origin=origin, name=f"bone{n}")


def _steps_per_drr(renderer: DRRRenderer, roi, pose: np.ndarray) -> float:
    """Mean number of ray-marching steps per DRR before empty-space skipping, at ``pose`` (host
    estimate; the timed poses differ from it by a few mm and degrees)."""
    from core.render.reference import _clip_rays

    vol = renderer.volumes[0]
    counts = []
    for cam in renderer.cameras:
        u0, v0, w, h = (int(a) for a in roi)
        vv, uu = np.mgrid[v0 : v0 + h, u0 : u0 + w]
        src, d = cam.rays(np.stack([uu, vv], -1).reshape(-1, 2))
        t0, t1 = _clip_rays(vol, pose, src, d)
        counts.append(np.ceil(np.maximum(t1 - t0, 0) / renderer.step_mm).sum())
    return float(np.mean(counts))


def _poses(n: int, seed: int) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(seed)
    T = np.tile(np.eye(4), (n, 1, 1))
    T[:, :3, :3] = Rotation.from_rotvec(rng.normal(0, np.deg2rad(3), (n, 3))).as_matrix()
    T[:, :3, 3] = rng.normal(0, 3.0, (n, 3))
    return T


def _time(fn, sync, repeats: int) -> float:
    fn()
    sync()
    best = np.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        sync()
        best = min(best, time.perf_counter() - t0)
    return best


def _case(renderer: DRRRenderer, n_poses: int, n_views: int, roi, scale: float, repeats: int) -> dict:
    poses = _poses(n_poses, 1)[:, None]
    views = list(range(n_views))
    dev = renderer.device

    def fn():
        return renderer.render(poses, views=views, roi=roi, scale=scale)

    sec = _time(fn, lambda: wp.synchronize_device(dev), repeats)
    n_drr = n_poses * n_views
    return {
        "poses": n_poses,
        "views": n_views,
        "drrs_per_launch": n_drr,
        "seconds_per_launch": sec,
        "ms_per_drr": 1e3 * sec / n_drr,
        "us_per_drr": 1e6 * sec / n_drr,
        "repeats": repeats,
    }


CONFIGS = {
    "texture": {"interpolation": "texture"},  # the CUDA default: 16-bit texture atlas
    "texture_float32": {"interpolation": "texture", "texture_dtype": "float32"},
    "trilinear": {"interpolation": "trilinear"},
}


def run_drr_benchmark(*, devices: list[str] | None = None, quick: bool = False,
                      interpolations: tuple[str, ...] | None = None) -> dict:
    """Run the DRR benchmark on each device and return a JSON-serialisable dict.

    Parameters
    ----------
    devices : list of str, optional
        Warp devices; default ``["cpu"]`` plus ``"cuda:0"`` when present.
    quick : bool
        Smaller batches and fewer repeats (a smoke run, e.g. in tests).
    interpolations : tuple of str, optional
        Renderer configurations, keys of :data:`CONFIGS`. Default: all on CUDA,
        ``("trilinear",)`` on the CPU.
    """
    wp.init()
    if devices is None:
        devices = ["cpu"] + (["cuda:0"] if wp.is_cuda_available() else [])
    result = {
        "benchmark": "drr",
        "warp": wp.__version__,
        "machine": {
            "platform": platform.platform(),
            "processor": platform.processor() or platform.machine(),
            "cpu_count": os.cpu_count(),
        },
        "reference_h100": REFERENCE_H100,
        "target_factor": TARGET_FACTOR,
        "targets_h100": TARGETS_H100,
        "quick": quick,
        "devices": {},
    }
    rig = _bench_rig()
    ct_shape = (300, 512, 512) if not quick else (60, 96, 96)
    bone_shape = (150, 150, 150) if not quick else (40, 40, 40)
    spacing = 0.5 if not quick else 2.0
    ct = _phantom(ct_shape, spacing, 0)
    bone = _bone(bone_shape[0], 0.3 if not quick else 0.5, 1)
    bone_transfer = HUTransfer(threshold=150.0)  # a bone DRR: soft tissue is not rendered
    for dev_name in devices:
        dev = wp.get_device(dev_name)
        cuda = dev.is_cuda
        interps = interpolations or (tuple(CONFIGS) if cuda else ("trilinear",))
        batch = 64 if cuda else (2 if quick else 8)
        repeats = (20 if not quick else 3) if cuda else 1
        ct_pixels = 1024 if (cuda or not quick) else 128
        entry = {"name": dev.name, "is_cuda": cuda, "interpolations": {}}
        for interp in interps:
            cases = {}
            r_ct = DRRRenderer(rig, [ct], device=dev_name, **CONFIGS[interp])
            # the whole detector (the quick run times its central ct_pixels² instead)
            c0 = (1024 - ct_pixels) // 2
            full = np.array([c0, c0, ct_pixels, ct_pixels])
            cases["ct_1024"] = {
                "volume_ijk": list(ct.shape_ijk),
                "image": [ct_pixels, ct_pixels],
                "single": _case(r_ct, 1, 1, full, 1.0, repeats),
            }
            if cuda or not quick:
                cases["ct_1024"]["batched"] = _case(r_ct, batch, 2, full, 1.0, max(1, repeats // 4))
            del r_ct
            r_bone = DRRRenderer(rig, [bone], device=dev_name, transfer=bone_transfer,
                                 **CONFIGS[interp])
            side = 300 if not quick else 64
            roi = np.array([512 - side // 2, 512 - side // 2, side, side])
            cases["bone_roi_300"] = {
                "volume_ijk": list(bone.shape_ijk),
                "image": [side, side],
                "single": _case(r_bone, 1, 2, roi, 1.0, repeats),
                "batched": _case(r_bone, batch, 2, roi, 1.0, repeats),
                "march_steps_per_drr": _steps_per_drr(r_bone, roi, np.eye(4)),
                "occupied_fraction_of_box": float((bone_transfer(bone.data) > 0).mean()),
            }
            if cuda and not quick:
                scan = {}
                for bd in (64, 128, 256, 512):
                    r_bone.block_dim = bd
                    r_bone._launches.clear()
                    scan[str(bd)] = _case(r_bone, batch, 2, roi, 1.0, repeats)["us_per_drr"]
                r_bone.block_dim = 128
                r_bone._launches.clear()
                cases["bone_roi_300"]["batched_us_per_drr_by_block_dim"] = scan
            if cuda and interp != "trilinear":
                exact = DRRRenderer(rig, [bone], device=dev_name, interpolation="trilinear",
                                    transfer=bone_transfer)
                poses = _poses(4, 2)[:, None]
                a = r_bone.render(poses, roi=roi).numpy()
                e = exact.render(poses, roi=roi).numpy()
                cases["bone_roi_300"]["texture_vs_exact"] = {
                    "max_abs_diff_rel_to_max": float(np.abs(a - e).max() / e.max()),
                    "mean_abs_diff_rel_to_mean": float(np.abs(a - e).mean() / e[e > 0].mean()),
                }
                # the device's exact path against the independent numpy reference (small ROI)
                small = np.array([480, 480, 64, 64])
                got = exact.render(poses[:1], views=[1], roi=small).item(0, 0, 0)
                ref = render_reference(rig[1], bone.to_attenuation(bone_transfer), poses[0, 0],
                                       step_mm=exact.step_mm, roi=tuple(small))
                cases["bone_roi_300"]["exact_vs_numpy_reference_max_rel"] = float(
                    np.abs(got - ref).max() / ref.max()
                )
                del exact
            b = cases["bone_roi_300"]
            b["gsteps_per_s_batched"] = b["march_steps_per_drr"] / b["batched"]["us_per_drr"] / 1e3
            del r_bone
            if cuda and not quick:
                ct_ms = cases["ct_1024"]["single"]["ms_per_drr"]
                bone_us = cases["bone_roi_300"]["batched"]["us_per_drr"]
                cases["ratio_to_reference"] = {
                    "ct_1024_single": ct_ms / REFERENCE_H100["ct_1024_single_ms"],
                    "bone_roi_300_batched": bone_us / REFERENCE_H100["bone_roi_300_batched_us"],
                    "ct_within_target": bool(ct_ms <= TARGETS_H100["ct_1024_single_ms"]),
                    "bone_within_target": bool(bone_us <= TARGETS_H100["bone_roi_300_batched_us"]),
                }
            entry["interpolations"][interp] = cases
        result["devices"][dev_name] = entry
    return result


def main() -> None:  # pragma: no cover - convenience for `python -m core.studies.render.benchmark`
    import argparse
    import json

    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--device", action="append")
    ap.add_argument("--quick", action="store_true")
    a = ap.parse_args()
    print(json.dumps(run_drr_benchmark(devices=a.device, quick=a.quick), indent=2))


if __name__ == "__main__":  # pragma: no cover
    main()
