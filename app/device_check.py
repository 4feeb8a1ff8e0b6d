"""Which device will compute DRRs and tracking, and what the CPU costs when no CUDA GPU is found.

:func:`probe` asks Warp for CUDA devices (``wp.get_cuda_device_count()``); it imports and
initialises Warp, which takes a few seconds, so the window calls it in a worker thread
(:mod:`app.welcome`). :func:`describe` turns the answer into the sentence the welcome page shows.

The speeds quoted are measured ones, copied from ``resources/benchmarks/tracking_cpu_quick.json``
(CPU, quick sizes) and ``resources/benchmarks/tracking_h100.json`` (NVIDIA H100, full sizes);
``tests/app/test_welcome.py`` checks they still match those files.
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["CPU_BENCH", "GPU_BENCH", "DeviceInfo", "cpu_slowdown", "describe", "probe"]

# One bone tracked end to end (tracking benchmark, 'one_bone.end_to_end.ms_per_frame').
CPU_BENCH = {"file": "tracking_cpu_quick.json", "ms_per_frame": 1888.417995375221, "pixels": 192,
             "voxel_mm": 1.0, "device_name": "CPU"}
GPU_BENCH = {"file": "tracking_h100.json", "ms_per_frame": 37.84877778000009, "pixels": 1024,
             "voxel_mm": 0.5, "device_name": "NVIDIA H100 80GB HBM3"}


@dataclass(frozen=True)
class DeviceInfo:
    """What :func:`probe` found: CUDA device names (empty: the CPU is used), or the error that
    kept Warp from starting."""

    cuda_devices: tuple[str, ...] = ()
    error: str | None = None
    warp_version: str | None = None

    @property
    def uses_cpu(self) -> bool:
        return not self.cuda_devices


def probe() -> DeviceInfo:
    """Initialise Warp and list its CUDA devices; never raises (an error is in ``error``)."""
    try:
        import warp as wp

        wp.config.quiet = True
        wp.init()
        n = int(wp.get_cuda_device_count())
        names = tuple(str(wp.get_device(f"cuda:{i}").name) for i in range(n))
        return DeviceInfo(cuda_devices=names, warp_version=str(wp.config.version))
    except Exception as exc:  # reported on the welcome page: DRRs then cannot run at all
        return DeviceInfo(error=f"{type(exc).__name__}: {exc}")


def cpu_slowdown() -> float:
    """How many times longer one frame of one bone takes on the CPU than on the GPU, in the two
    benchmarks (the GPU's frames were also (1024/192)² = 28× larger, so this is a lower bound)."""
    return CPU_BENCH["ms_per_frame"] / GPU_BENCH["ms_per_frame"]


def describe(info: DeviceInfo) -> tuple[str, str]:
    """(level, text): level is 'gpu', 'cpu' or 'error'; text is the sentence for the user."""
    if info.error is not None:
        return "error", (f"Warp could not start ({info.error}): DRRs, tracking and calibration "
                         "will not work. Reinstall Talus or see installer/README.md.")
    if info.cuda_devices:
        names = ", ".join(info.cuda_devices)
        return "gpu", f"CUDA GPU found ({names}): DRRs and tracking run on the GPU."
    slow = cpu_slowdown()
    cpu_s = CPU_BENCH["ms_per_frame"] / 1000
    gpu_ms = GPU_BENCH["ms_per_frame"]
    return "cpu", (
        f"No CUDA GPU found: DRRs and tracking will run on the CPU. Tracking on the CPU is about "
        f"{slow:.0f}× slower: one bone took {cpu_s:.1f} s per frame of {CPU_BENCH['pixels']} px "
        f"({CPU_BENCH['voxel_mm']:g} mm voxels) on a CPU, against {gpu_ms:.0f} ms per frame of "
        f"{GPU_BENCH['pixels']} px ({GPU_BENCH['voxel_mm']:g} mm voxels) on an NVIDIA H100; finer CT "
        "voxels, larger views and a first frame take longer. Viewing, editing poses and exporting "
        "are not affected. With an NVIDIA GPU and its driver installed, Talus uses it on the next "
        "start.")
