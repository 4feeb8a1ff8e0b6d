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
* With pytest-xdist (``-n 2 --dist loadgroup``, as ``installer/dev.sh test`` and so CI's
  ``.ci/run`` run the suite) the tests are sent to the workers in groups
  (:func:`pytest_xdist_make_scheduler`): a file's tests stay together (its module fixtures are
  built once), files that share an expensive session fixture share a group (the fixture is built
  by one worker only), and every GUI test (marked ``gui`` or using pytest-qt) is in one group, so
  windows never open on the shared X display from two processes at once. Each worker has its own
  XDG cache and settings folders; Warp's kernel cache is shared (Warp builds a module in a folder
  of its own process and renames it into place). The groups go out longest first, by the seconds
  each file took in the last such run (kept in pytest's cache, ``.pytest_cache``), so that the
  two workers finish together; without that record, largest first by number of tests.
"""

from __future__ import annotations

import json
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
    worker = os.environ.get("PYTEST_XDIST_WORKER", "")  # "gw0", "gw1"... under pytest-xdist
    own = root / worker if worker else root
    os.environ["XDG_CACHE_HOME"] = str(own / "xdg")
    os.environ["TALUS_SETTINGS_DIR"] = str(own / "settings")  # never the user's own settings
    # compiled kernels only depend on their source and Warp's version (its own subfolder)
    os.environ["WARP_CACHE_PATH"] = os.environ.get("TALUS_TEST_KERNEL_CACHE") or str(root / "warp")
    if has_display():
        # VTK's Qt interactor needs X11 (Qt's offscreen/wayland platforms are not reliable)
        os.environ.setdefault("QT_QPA_PLATFORM", "xcb")
    if not worker and getattr(config.option, "dist", "no") == "loadgroup":  # xdist's controller
        os.environ[_GROUPS_FILE] = str(root / "xdist_groups.json")  # its workers inherit this
        if sys.flags.utf8_mode:
            # as this process: Python started in the C locale reads and writes text as UTF-8 even
            # after a library sets the C locale again (a worker, started in the C.UTF-8 locale
            # this process chose, decoded a child's UTF-8 help text as ASCII)
            os.environ.setdefault("PYTHONUTF8", "1")
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


def _skip_gui_without_display(items: list[pytest.Item]) -> None:
    reason = _gui_skip_reason()
    if reason is None:
        return
    skip = pytest.mark.skip(reason=reason)
    for item in items:
        if "gui" in item.keywords:
            item.add_marker(skip)


# The tests' own session fixtures cheap enough to build in every worker: they do not tie files to one
# xdist group (plugins' session fixtures, such as pytest-qt's qapp, never do). demo_walk_48 and
# keyed: the demo walk built once per process (tests/core/tracking/demo_walk.py, ~1 s), or a copy.
_CHEAP_SESSION_FIXTURES = frozenset({"sample_data", "wrist", "rng", "rig", "sizes", "smooth_pair",
                                     "demo_walk_48", "keyed"})
_GROUPS_FILE = "TALUS_XDIST_GROUPS"  # where the workers write the groups for the controller


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    _skip_gui_without_display(items)
    path = os.environ.get(_GROUPS_FILE)
    if path and os.environ.get("PYTEST_XDIST_WORKER"):
        groups = json.dumps(_xdist_groups(items), indent=0, sort_keys=True)
        tmp = Path(f"{path}.{os.environ['PYTEST_XDIST_WORKER']}")
        tmp.write_text(groups)
        os.replace(tmp, path)  # every worker collects the same tests, so writes the same groups


def _xdist_groups(items: list[pytest.Item]) -> dict[str, str]:
    """``{test file: group}``: a file's tests form one group, merged with the files that share one
    of its expensive session fixtures, and one group holds every GUI test (see the module doc)."""
    parent: dict[str, str] = {}

    def find(x: str) -> str:
        while parent.setdefault(x, x) != x:
            parent[x] = parent[parent[x]]
            x = parent[x]
        return x

    def union(a: str, b: str) -> None:
        ra, rb = find(a), find(b)
        if ra != rb:
            parent[max(ra, rb)] = min(ra, rb)

    for item in items:
        file = item.nodeid.split("::")[0]
        find(file)
        if item.get_closest_marker("gui") or {"qtbot", "qapp"} & set(getattr(item, "fixturenames", ())):
            union(file, "gui")
        info = getattr(item, "_fixtureinfo", None)
        for name, defs in (info.name2fixturedefs.items() if info else ()):
            own = defs and defs[-1].baseid.startswith("tests")  # defined in a conftest.py here
            if own and defs[-1].scope == "session" and name not in _CHEAP_SESSION_FIXTURES:
                union(file, f"fixture {defs[-1].baseid}::{name}")
    return {file: find(file) for file in list(parent) if file.endswith(".py")}


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_make_scheduler(config: pytest.Config, log):
    """``--dist loadgroup``: xdist's scheduling by scope, a scope being a group of
    :func:`_xdist_groups` (xdist's own ``xdist_group`` marks do not reach the controller with
    pytest 9, whose node ids it can no longer change)."""
    if config.getvalue("dist") != "loadgroup":
        return None
    from xdist.scheduler import LoadScopeScheduling

    class GroupScheduling(LoadScopeScheduling):
        groups: dict[str, str] | None = None

        ordered = False

        def _assign_work_unit(self, node) -> None:
            if not self.ordered:  # the first call: the queue holds every group
                self.ordered = True
                seconds = _cache_get(config, _SECONDS_KEY)
                if seconds:
                    # the groups in order of their seconds, longest first (xdist orders them by
                    # number of tests): each worker's last groups are short ones
                    n = sum(len(unit) for unit in self.workqueue.values())
                    per_test = sum(seconds.values()) / max(1, n)  # a new file: a mean test's time
                    cost: dict[str, float] = {}
                    for scope, unit in self.workqueue.items():
                        files = {nodeid.split("::")[0] for nodeid in unit}
                        cost[scope] = sum(seconds[f] if f in seconds else
                                          per_test * sum(1 for i in unit if i.startswith(f + "::"))
                                          for f in files)
                    order = sorted(self.workqueue.items(), key=lambda su: -cost[su[0]])  # stable
                    self.workqueue.clear()
                    self.workqueue.update(order)
            super()._assign_work_unit(node)

        def _split_scope(self, nodeid: str) -> str:
            file = nodeid.split("::")[0]
            if self.groups is None:  # written by the workers before they sent their collection
                groups_file = Path(os.environ.get(_GROUPS_FILE, "-"))
                self.groups = json.loads(groups_file.read_text()) if groups_file.is_file() else {}
            # without the file (never seen): at least the window tests stay in one worker
            return self.groups.get(file, "tests/app" if file.startswith("tests/app/") else file)

    return GroupScheduling(config, log)


_SECONDS_KEY = "talus/xdist_file_seconds"  # {test file: seconds} of the last --dist loadgroup run
_file_seconds: dict[str, float] = {}


def _cache_get(config: pytest.Config, key: str):
    cache = getattr(config, "cache", None)  # None with -p no:cacheprovider
    return cache.get(key, None) if cache is not None else None


def pytest_runtest_logreport(report: pytest.TestReport) -> None:
    """The controller of a ``--dist loadgroup`` run adds up each file's seconds (set-up, call and
    tear-down of its tests, as the workers report them) for the next run's order."""
    if not os.environ.get("PYTEST_XDIST_WORKER"):
        file = report.nodeid.split("::")[0]
        _file_seconds[file] = _file_seconds.get(file, 0.0) + report.duration


def pytest_sessionfinish(session: pytest.Session, exitstatus: int) -> None:
    config = session.config
    cache = getattr(config, "cache", None)
    if (cache is not None and _file_seconds and not os.environ.get("PYTEST_XDIST_WORKER")
            and getattr(config.option, "dist", "no") == "loadgroup" and not config.option.keyword
            and not config.option.markexpr):
        seconds = _cache_get(config, _SECONDS_KEY) or {}
        seconds.update({f: round(s, 2) for f, s in _file_seconds.items()})
        cache.set(_SECONDS_KEY, seconds)


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
