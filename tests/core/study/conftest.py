"""Fixtures for the study-store tests: a small synthetic rig on disk and two TIFF-folder views."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
import tifffile

from core.geometry import write_mayacam
from core.synthetic import foot_rig

PIXELS = 32
N_FRAMES = 6


@pytest.fixture
def rig_files(tmp_path) -> list[Path]:
    """Two MayaCam 2.0 files of a 32x32-pixel synthetic rig."""
    rig = foot_rig(seed=3, pixels=PIXELS)
    out = []
    for i, cam in enumerate(rig):
        p = tmp_path / "calib" / f"cam{i + 1}.txt"
        p.parent.mkdir(parents=True, exist_ok=True)
        write_mayacam(cam, p)
        out.append(p)
    return out


def write_tiff_folder(folder: Path, n: int, *, shape=(PIXELS, PIXELS), seed=0, start=0) -> np.ndarray:
    folder.mkdir(parents=True, exist_ok=True)
    frames = np.random.default_rng(seed).integers(0, 4096, size=(n, *shape), dtype=np.uint16)
    for k in range(n):
        tifffile.imwrite(folder / f"frame_{start + k:04d}.tif", frames[k])
    return frames


@pytest.fixture
def make_tiff_folder():
    """``make(folder, n, shape=(32, 32), seed=0)`` writes n uint16 TIFF frames; returns the folder."""

    def make(folder: Path, n: int, **kw) -> Path:
        write_tiff_folder(folder, n, **kw)
        return folder

    return make


@pytest.fixture
def views(tmp_path) -> tuple[list[Path], list[np.ndarray]]:
    """Two folders of 6 uint16 frames (12-bit values) and their ground-truth pixels."""
    paths, frames = [], []
    for i in range(2):
        p = tmp_path / "raw" / f"cam{i + 1}"
        frames.append(write_tiff_folder(p, N_FRAMES, seed=i))
        paths.append(p)
    return paths, frames


def run_python(code: str, *, timeout: float = 60.0, check: bool = True) -> subprocess.CompletedProcess:
    """Run ``code`` in a fresh interpreter of this environment (the project is importable)."""
    env = dict(os.environ)
    env["PYTHONPATH"] = str(Path(__file__).resolve().parents[3]) + os.pathsep + env.get("PYTHONPATH", "")
    proc = subprocess.run(
        [sys.executable, "-c", textwrap.dedent(code)],
        capture_output=True, text=True, timeout=timeout, env=env,
    )
    if check and proc.returncode != 0:
        raise AssertionError(f"child failed ({proc.returncode}):\n{proc.stdout}\n{proc.stderr}")
    return proc


def start_python(code: str) -> subprocess.Popen:
    """Start ``code`` in a child interpreter; stdout is a pipe (text)."""
    env = dict(os.environ)
    env["PYTHONPATH"] = str(Path(__file__).resolve().parents[3]) + os.pathsep + env.get("PYTHONPATH", "")
    return subprocess.Popen(
        [sys.executable, "-c", textwrap.dedent(code)], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
        text=True, env=env,
    )


@pytest.fixture
def python_child():
    """Helpers to run/start child interpreters; started children are killed at teardown."""
    started: list[subprocess.Popen] = []

    class Helper:
        run = staticmethod(run_python)

        @staticmethod
        def start(code: str) -> subprocess.Popen:
            p = start_python(code)
            started.append(p)
            return p

    yield Helper
    for p in started:
        if p.poll() is None:
            p.kill()
        p.wait(timeout=30)
        for s in (p.stdout, p.stderr):
            if s is not None:
                s.close()


@pytest.fixture
def talus_study(tmp_path, rig_files, views) -> Path:
    """A study folder with one CT (a placeholder file, 1 mm voxels), the talus, and the trial walk01 of
    the first view's frames: the journal and lock tests' smallest study."""
    from core.study import Study

    with Study.create(tmp_path / "st") as st:
        st.add_calibration("day1", rig_files)
        vol = tmp_path / "talus.tif"
        vol.write_bytes(b"placeholder")
        st.add_volume("ct", vol, voxel_size_mm=[1, 1, 1])
        st.add_bone("talus", volume="ct")
        st.add_trial("walk01", views[0], calibration="day1", bones=["talus"])
    return tmp_path / "st"
