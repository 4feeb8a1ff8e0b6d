"""Shared test set-up for all tiers (tests/core, tests/app, architecture tests).

* Caches (``XDG_CACHE_HOME``, Warp's kernel cache ``WARP_CACHE_PATH``) go to a temporary folder
  for the whole session: ``$TALUS_TEST_CACHE_DIR`` when set (``installer/dev.sh test`` sets it),
  otherwise a fresh folder removed at the end. Warp's compiled kernels go to
  ``$TALUS_TEST_KERNEL_CACHE`` instead when it is set (``installer/dev.sh test`` keeps one beside
  the virtual environment, so a second run does not compile them again). They are set in
  :func:`pytest_configure`, before any test module imports Warp.
* Tests marked ``gui`` are skipped, with a reason, when there is no X display (run them under
  ``xvfb-run``; see README).
* The ``sample_data`` fixture gives the real-data folder (``../shared/data`` next to the project
  or ``$TALUS_SAMPLE_DATA``) and skips the test when it is absent.
"""

from __future__ import annotations

import os
import shutil
import sys
import tempfile
from pathlib import Path

import pytest

_CACHE_VARS = ("XDG_CACHE_HOME", "WARP_CACHE_PATH", "TALUS_SETTINGS_DIR")
_session_cache: dict[str, object] = {}


def pytest_configure(config: pytest.Config) -> None:
    base = os.environ.get("TALUS_TEST_CACHE_DIR")
    owned = not base
    if owned:
        base = tempfile.mkdtemp(prefix="talus-test-cache-")
    root = Path(base)
    _session_cache.update(
        root=root, owned=owned, saved={k: os.environ.get(k) for k in _CACHE_VARS}
    )
    os.environ["XDG_CACHE_HOME"] = str(root / "xdg")
    os.environ["TALUS_SETTINGS_DIR"] = str(root / "settings")  # never the user's own settings
    # compiled kernels only depend on their source and Warp's version (its own subfolder)
    os.environ["WARP_CACHE_PATH"] = os.environ.get("TALUS_TEST_KERNEL_CACHE") or str(root / "warp")
    if has_display():
        # VTK's Qt interactor needs X11 (Qt's offscreen/wayland platforms are not reliable)
        os.environ.setdefault("QT_QPA_PLATFORM", "xcb")
    if "warp" in sys.modules:  # imported by a plugin before us: point its config there too
        sys.modules["warp"].config.kernel_cache_dir = os.environ["WARP_CACHE_PATH"]


def pytest_unconfigure(config: pytest.Config) -> None:
    saved = _session_cache.get("saved") or {}
    for key, value in saved.items():
        if value is None:
            os.environ.pop(key, None)
        else:
            os.environ[key] = value
    if _session_cache.get("owned"):
        shutil.rmtree(_session_cache["root"], ignore_errors=True)


def has_display() -> bool:
    """True when Qt's xcb platform (needed by the VTK interactor) can open a window."""
    return bool(os.environ.get("DISPLAY"))


def _gui_skip_reason() -> str | None:
    if not has_display():
        return (
            "gui test needs an X display: DISPLAY is not set (run under "
            "xvfb-run -a -s '-screen 0 1280x1024x24', or `bash installer/dev.sh test`)"
        )
    platform = os.environ.get("QT_QPA_PLATFORM", "xcb")
    if platform != "xcb":
        return f"gui test needs QT_QPA_PLATFORM=xcb for the VTK interactor, got {platform!r}"
    return None


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    reason = _gui_skip_reason()
    if reason is None:
        return
    skip = pytest.mark.skip(reason=reason)
    for item in items:
        if "gui" in item.keywords:
            item.add_marker(skip)


def sample_data_dir() -> Path:
    """Where the real sample data is expected (it may be absent)."""
    env = os.environ.get("TALUS_SAMPLE_DATA")
    if env:
        return Path(env).expanduser()
    return Path(__file__).resolve().parents[2] / "shared" / "data"


@pytest.fixture(scope="session")
def sample_data() -> Path:
    """Path of the real sample data folder (e.g. ``sample_data / "autoscoper_wrist"``).

    Skips the test when the folder is absent (a user's own clone has no ``../shared/data``).
    """
    path = sample_data_dir()
    if not path.is_dir():
        why = f"sample data not found at {path} (set TALUS_SAMPLE_DATA to its folder)"
        pytest.skip(reason=why)
    return path


@pytest.fixture(scope="session")
def wrist(sample_data):
    """The Autoscoper wrist sample (:func:`core.samples.load_wrist_sample`), loaded once; skips
    the test when its folder is absent."""
    from core.samples import load_wrist_sample

    folder = sample_data / "autoscoper_wrist"
    if not folder.is_dir():
        pytest.skip(reason=f"wrist sample not found at {folder}")
    return load_wrist_sample(folder)
