"""The wheel and sdist that a lab installs: built by the project's build backend (setuptools,
through ``pip wheel`` and ``build_meta.build_sdist``) from a copy of the sources, checked for
every package and the data read at run time, and installed into a fresh virtual environment
where ``talus`` runs.

The environment is made with ``--no-deps``: the dependencies come from the test environment's
own site-packages (appended to the new one's path), so the test needs no download beyond the
build backend pip fetches when the test environment lacks a recent one, and stays well under a
minute. A full ``pip install 'talus-biplane[gui]'`` with its dependencies, and a CUDA-free
``talus demo --no-gui``, are run by ``bash installer/build.sh wheel`` + installer/README.md.
"""

from __future__ import annotations

import email
import os
import shutil
import subprocess
import sys
import sysconfig
import tarfile
import venv
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _packages(top: str) -> set[str]:
    """Every package (folder with __init__.py) under ``top`` of the checkout, dotted."""
    return {".".join(p.parent.relative_to(ROOT).parts) for p in (ROOT / top).rglob("__init__.py")
            if "__pycache__" not in p.parts}


def _run(cmd, **kw) -> subprocess.CompletedProcess:
    r = subprocess.run([str(c) for c in cmd], capture_output=True, text=True, timeout=240, **kw)
    assert r.returncode == 0, f"{cmd} exited {r.returncode}:\n{r.stdout[-3000:]}\n{r.stderr[-3000:]}"
    return r


def _backend_ok() -> bool:
    """The test environment can build without fetching setuptools/wheel (no build isolation)."""
    try:
        import setuptools
        import wheel  # noqa: F401
    except ImportError:
        return False
    return int(setuptools.__version__.split(".")[0]) >= 68


@pytest.fixture(scope="module")
def built(tmp_path_factory) -> tuple[Path, Path]:
    base = tmp_path_factory.mktemp("packaging")
    src = base / "src"
    src.mkdir()
    for name in ("pyproject.toml", "README.md"):
        shutil.copy2(ROOT / name, src / name)
    ignore = shutil.ignore_patterns("__pycache__", "*.pyc", "*.egg-info")
    for top in ("core", "app"):
        shutil.copytree(ROOT / top, src / top, ignore=ignore)
    dist = base / "dist"
    isolation = ["--no-build-isolation"] if _backend_ok() else []
    _run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", *isolation, "-w", dist, src])
    sdist_hook = "import sys; from setuptools import build_meta as b; b.build_sdist(sys.argv[1])"
    _run([sys.executable, "-c", sdist_hook, dist], cwd=src)
    (wheel,) = dist.glob("talus_biplane-*-py3-none-any.whl")
    (sdist,) = dist.glob("talus[-_]biplane-*.tar.gz")  # normalised by setuptools >= 69
    return wheel, sdist


def test_wheel_holds_every_package_and_run_time_data(built):
    wheel, _ = built
    with zipfile.ZipFile(wheel) as z:
        names = set(z.namelist())
        meta = email.message_from_string(z.read(next(n for n in names if n.endswith("METADATA"))).decode())
        entry = z.read(next(n for n in names if n.endswith("entry_points.txt"))).decode()
    packages = {n.rsplit("/", 1)[0].replace("/", ".") for n in names if n.endswith("/__init__.py")}
    expected = _packages("core") | _packages("app")
    assert expected <= packages, f"packages missing from the wheel: {sorted(expected - packages)}"
    assert "app/icons/talus.png" in names  # the window icon, read through app.welcome.ICON
    for data in (ROOT / "app").rglob("*.json"):
        assert data.relative_to(ROOT).as_posix() in names
    assert not any(n.startswith(("tests/", "resources/", "installer/")) for n in names)
    assert "talus = app.cli:main" in entry
    requires = meta.get_all("Requires-Dist")
    assert any(r.startswith("warp-lang") for r in requires)
    assert any(r.startswith("PySide6-Essentials") and 'extra == "gui"' in r for r in requires)


def test_sdist_rebuilds_the_wheel(built):
    _, sdist = built
    with tarfile.open(sdist) as t:
        names = {n.split("/", 1)[1] for n in t.getnames() if "/" in n}
    assert {"pyproject.toml", "README.md", "app/cli.py", "core/__init__.py", "app/icons/talus.png"} <= names


def test_installed_wheel_runs_talus(built, tmp_path):
    wheel, _ = built
    env_dir = tmp_path / "venv"
    venv.EnvBuilder(with_pip=False, system_site_packages=True).create(env_dir)
    bindir = env_dir / ("Scripts" if os.name == "nt" else "bin")
    py = bindir / ("python.exe" if os.name == "nt" else "python")
    site = Path(_run([py, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"]).stdout.strip())
    # the test environment's packages, after the new environment's own (a plain path: its .pth
    # files, the editable install of this checkout among them, are not read)
    (site / "test_env.pth").write_text(sysconfig.get_paths()["purelib"] + "\n", encoding="utf-8")
    _run([sys.executable, "-m", "pip", "--python", py, "install", "-q", "--no-deps", "--no-index", wheel])
    env = {**os.environ, "PYTHONNOUSERSITE": "1"}
    env.pop("PYTHONPATH", None)
    where = _run([py, "-c", "import core, app.cli, app.welcome as w; print(core.__file__); "
                  "print(w.ICON, w.ICON.is_file())"], cwd=tmp_path, env=env).stdout.split("\n")
    assert Path(where[0]).is_relative_to(site), f"core imported from {where[0]}, not the installed wheel"
    assert Path(where[1].split()[0]).is_relative_to(site) and where[1].endswith("True")
    talus = bindir / ("talus.exe" if os.name == "nt" else "talus")
    from core import __version__

    assert _run([talus, "--version"], cwd=tmp_path, env=env).stdout.strip() == f"talus {__version__}"
    assert "--pixels" in _run([talus, "demo", "--help"], cwd=tmp_path, env=env).stdout
