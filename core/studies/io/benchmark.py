"""Fluoro sequence read speed: random access and sequential throughput of cine and TIFF files.

Run ``python -m core.studies.io.benchmark [--quick] [--out FILE] [--dir DIR]``; prints JSON (machine,
sizes, times). The default case is the issue's: a 1000-frame 1024² 12-bit **packed** (P12L) cine
(~1.5 GB) and the same frames as a 16-bit multipage TIFF (~2 GB), written to a temporary folder
(removed afterwards; the run scales the frame count down, and says so, when the disk is short).

For each file it measures

* ``open_ms``: opening (headers, image table; no pixels) and the resident memory it added;
* ``random_ms_per_frame``: reading frame ``k`` for 200 random ``k`` (the pixels are touched, so
  a memory-mapped frame is really read), median and mean;
* ``sequential_fps``: reading every frame in order;

twice: ``warm`` (file in the OS page cache, as right after writing it) and ``cold`` (the file's
pages evicted with ``posix_fadvise(DONTNEED)`` before each pass, so the disk is read; Linux only).
Frames are checked against the values written. Times are wall-clock ``time.perf_counter``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import tifffile

from core.io.cine import CineSequence
from core.io.cine_writer import write_cine
from core.io.sequences import MultipageTiffSequence

__all__ = ["run"]


def _frame(base: np.ndarray, k: int) -> np.ndarray:
    """Deterministic 12-bit test frame ``k`` (cheap to regenerate for checking)."""
    return (base + np.uint16(7 * k)) & np.uint16(0x0FFF)


def _rss_mb() -> float:
    """Current resident set size (MB) from /proc, else the peak from getrusage."""
    try:
        with open("/proc/self/statm") as fh:
            return int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20
    except (OSError, ValueError):
        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def _evict(path: Path) -> bool:
    if not hasattr(os, "posix_fadvise"):
        return False
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
        os.posix_fadvise(fd, 0, 0, os.POSIX_FADV_DONTNEED)
    finally:
        os.close(fd)
    return True


def _measure(opener, path: Path, base: np.ndarray, n: int, n_random: int, cold: bool, rng) -> dict:
    if cold and not _evict(path):
        return {"skipped": "posix_fadvise unavailable"}
    rss0 = _rss_mb()
    t0 = time.perf_counter()
    seq = opener(path)
    t_open = time.perf_counter() - t0
    first = seq[n // 2]
    checksum = int(first.max())
    rss_one = _rss_mb() - rss0
    ok = bool(np.array_equal(first, _frame(base, n // 2)))
    ks = rng.integers(0, n, size=n_random)
    times = []
    for k in ks:
        t0 = time.perf_counter()
        img = seq[int(k)]
        checksum += int(img[::64, ::64].sum()) + int(img[-1, -1])  # touch rows across the frame
        np.asarray(img).sum()
        times.append(time.perf_counter() - t0)
    ok &= bool(np.array_equal(seq[int(ks[0])], _frame(base, int(ks[0]))))
    if cold:
        _evict(path)
    t0 = time.perf_counter()
    for k in range(n):
        np.asarray(seq[k]).sum()
    t_seq = time.perf_counter() - t0
    seq.close()
    ms = np.array(times) * 1e3
    return {
        "open_ms": round(t_open * 1e3, 3),
        "rss_added_by_open_and_one_frame_mb": round(rss_one, 1),
        "random_ms_per_frame_median": round(float(np.median(ms)), 3),
        "random_ms_per_frame_mean": round(float(ms.mean()), 3),
        "random_frames": n_random,
        "sequential_fps": round(n / t_seq, 1),
        "sequential_mb_per_s": round(path.stat().st_size / 2**20 / t_seq, 1),
        "frames_verified": ok,
    }


def run(*, quick: bool = False, folder: str | os.PathLike | None = None, keep: bool = False) -> dict:
    """Write the test files, time them and return the JSON-ready result (see the module docstring)."""
    n, side, n_random = (50, 256, 20) if quick else (1000, 1024, 200)
    tmp = Path(tempfile.mkdtemp(prefix="talus-io-bench-", dir=folder))
    need = n * side * side * (1.5 + 2.0) * 1.05
    free = shutil.disk_usage(tmp).free
    note = ""
    if free < need:
        scale = free / need * 0.8
        n_new = max(10, int(n * scale))
        note = (
            f"disk short ({free / 2**30:.1f} GiB free, {need / 2**30:.1f} needed): "
            f"{n_new} frames instead of {n}"
        )
        n = n_new
    base = np.random.default_rng(0).integers(0, 4096, size=(side, side)).astype(np.uint16)
    cine, tif = tmp / "trial_cam1.cine", tmp / "trial_cam1.tif"
    try:
        t0 = time.perf_counter()
        write_cine(cine, (_frame(base, k) for k in range(n)), n_frames=n, storage="p12", frame_rate=1000)
        t_cine = time.perf_counter() - t0
        t0 = time.perf_counter()
        tifffile.imwrite(tif, (_frame(base, k) for k in range(n)), shape=(n, side, side), dtype=np.uint16,
                         photometric="minisblack", bigtiff=n * side * side * 2 > 2**31)
        t_tif = time.perf_counter() - t0
        rng = np.random.default_rng(1)
        results = {}
        for name, path, opener in (
            ("cine_p12", cine, CineSequence),
            ("tiff_uint16", tif, MultipageTiffSequence),
        ):
            with opener(path) as probe:
                mapped = bool(probe.memory_mapped)
            results[name] = {
                "file_mb": round(path.stat().st_size / 2**20, 1),
                "memory_mapped": mapped,
                "warm": _measure(opener, path, base, n, n_random, False, rng),
                "cold": _measure(opener, path, base, n, n_random, True, rng),
            }
        results["cine_p12"]["write_s"] = round(t_cine, 2)
        results["tiff_uint16"]["write_s"] = round(t_tif, 2)
    finally:
        if not keep:
            shutil.rmtree(tmp, ignore_errors=True)
    w = {k: results[k]["warm"] for k in ("cine_p12", "tiff_uint16")}
    rnd = {k: w[k]["random_ms_per_frame_median"] for k in w}
    return {
        "benchmark": "core.io sequence read",
        "machine": {
            "platform": platform.platform(),
            "processor": platform.processor() or platform.machine(),
            "cpu_count": os.cpu_count(),
            "python": sys.version.split()[0],
            "numpy": np.__version__,
            "tifffile": tifffile.__version__,
        },
        "device": "cpu + local disk (file I/O, no GPU involved)",
        "sizes": {"frames": n, "width": side, "height": side, "bits": 12, "quick": quick},
        "note": note,
        "results": results,
        "ratios": {
            "tiff_over_cine_random_ms_warm": round(rnd["tiff_uint16"] / rnd["cine_p12"], 3),
            "cine_over_tiff_sequential_fps_warm": round(
                w["cine_p12"]["sequential_fps"] / w["tiff_uint16"]["sequential_fps"], 3
            ),
        },
    }


def main(argv: list[str] | None = None, *, prog: str = "python -m core.studies.io.benchmark") -> int:
    ap = argparse.ArgumentParser(prog=prog,
                                 description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="50 frames of 256², a smoke run")
    ap.add_argument("--out", type=Path, help="also write the JSON to this file")
    ap.add_argument("--dir", type=Path, help="folder for the temporary test files (default: system temp)")
    args = ap.parse_args(argv)
    result = run(quick=args.quick, folder=args.dir)
    text = json.dumps(result, indent=2)
    if args.out:
        from core.io.atomic import atomic_write

        atomic_write(args.out, text + "\n")
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
