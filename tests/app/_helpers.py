"""Helpers shared by the GUI tests of tests/app (import: ``from tests.app._helpers import job_ends``)."""

from __future__ import annotations

import shutil
import threading
import time
from contextlib import contextmanager
from pathlib import Path

import pytest


def _fast_tracking():
    from core.tracking.register import Level, RegistrationOptions
    from core.tracking.trial import TrackingOptions

    return TrackingOptions(
        registration=RegistrationOptions(
            bounds=(4.0, 4.0), levels=(Level(2.0, "pattern", (0.5, 0.5), max_generations=30, tol_x=0.3),),
            refine=None),
        confidence=False, verify_restarts=0)


# Tracking options for tests of the window's plumbing (jobs, progress, journals, cancel), not of the
# tracker's accuracy: one pattern-search level at half resolution that converges in a few dozen
# evaluations, no restart check, no confidence. (One CMA-ES level at full resolution stopped on
# its generation budget, so every frame was flagged "not converged" and retried twice as wide:
# 37 s for 3 frames of one bone on the loaded 2-core machine, against 1.6 s with these.)
FAST_TRACKING = _fast_tracking()

class ErrorShown(RuntimeError):
    """The window reported an error the test did not expect, where users get a modal box
    (``tests/app/conftest.py``: raised by the test's wait). Not an AssertionError: ``qtbot.waitUntil``
    takes those from its callback as "not yet"."""


# The tests wait for the job's own end signal (finished, failed or cancelled), however long a
# loaded machine takes to get there (Warp compiles its kernels in the first render). This is only
# the ceiling for a job that never ends, not a time the work is expected to take.
HUNG_JOB_MS = 30 * 60_000


@contextmanager
def job_ends(qtbot, pool, key: str, expect: str = "finished"):
    """Run the block, then wait until the pool's newest job ``key`` ends; fail unless it ended as
    ``expect`` (``"finished"``, ``"failed"`` or ``"cancelled"``).

    Yields the list of ends seen so far (``(kind, payload)``), so a test can also wait for an
    earlier event inside the block without missing a failure. A failure or a cancellation ends the
    wait at once, and the test fails with the worker's message unless that end was expected.
    """
    ends: list[tuple[str, object]] = []

    def on_finished(k, result):
        if k == key:
            ends.append(("finished", result))

    def on_failed(k, message):
        if k == key:
            ends.append(("failed", message))

    def on_cancelled(k):
        if k == key:
            ends.append(("cancelled", None))

    slots = ((pool.finished, on_finished), (pool.failed, on_failed), (pool.cancelled, on_cancelled))
    for signal, slot in slots:
        signal.connect(slot)
    try:
        yield ends
        qtbot.waitUntil(lambda: bool(ends), timeout=HUNG_JOB_MS)
    finally:
        for signal, slot in slots:
            signal.disconnect(slot)
    kind, payload = ends[0]
    if kind != expect:
        pytest.fail(f"background job {key!r} {kind} instead of being {expect}: {payload}")


def copy_study(folder, tmp_path, name: str = "study") -> Path:
    """A private copy of a shared study folder (e.g. the ``demo_study`` fixture's), for a test that
    writes to it (the window journals every pose edit)."""
    return Path(shutil.copytree(folder, Path(tmp_path) / name))


@contextmanager
def main_window(qtbot, *, scene: bool = False, device: str | None = "cpu", size=None):
    """A shown :class:`~app.main_window.MainWindow`, closed on exit.

    ``scene=True`` creates the 3-D scene (a VTK ``QtInteractor``) as the window shows and waits
    for it; on exit the window's close must have closed that interactor too. Without it the scene
    pane stays a placeholder until something asks for it (``window.scene.ensure_interactor()``),
    which spares a test that never looks at the 3-D view the cost of an OpenGL context.
    """
    from app.main_window import MainWindow

    win = MainWindow(device=device, create_scene_on_show=scene)
    qtbot.addWidget(win)
    if size is not None:
        win.resize(*size)
    win.show()
    qtbot.waitExposed(win)
    if scene:
        qtbot.waitUntil(lambda: win.scene.plotter is not None, timeout=HUNG_JOB_MS)
    try:
        yield win
    finally:
        plotter = win.scene.plotter  # also one the test asked for
        win.close()  # closes the QtInteractor; a live one would crash the next test
        assert win.scene.plotter is None
        if plotter is not None:
            assert plotter._closed


def pause_after_first_frame(monkeypatch, *, until_cancelled: bool = False) -> threading.Event:
    """Make every tracking job (:func:`core.tracking.from_study.track_study`, as the window and the
    batch's in-process workers call it) wait after its first frame until the returned event is set
    or, with ``until_cancelled``, until the job's own cancel flag reads True. A test then acts while
    the job surely runs, however fast the machine tracks."""
    import core.tracking.from_study as from_study

    track_study, go_on = from_study.track_study, threading.Event()

    def paused(*args, progress, cancel=None, **kwargs):
        def first_then_wait(*a):
            progress(*a)
            deadline = time.monotonic() + HUNG_JOB_MS / 1000  # a job that is never let go
            while not (go_on.is_set() or (until_cancelled and cancel is not None and cancel())):
                assert time.monotonic() < deadline, "the paused tracking job was never let go"
                go_on.wait(0.02)

        return track_study(*args, progress=first_then_wait, cancel=cancel, **kwargs)

    monkeypatch.setattr(from_study, "track_study", paused)
    return go_on


def small_demo(out: Path) -> Path:
    """The 48² two-frame demo study the CLI tests share (CPU, no calibration session)."""
    from core.synthetic import make_demo_study

    make_demo_study(out, n_frames=2, pixels=48, spacing=3.0, tissue_spacing=6.0, device="cpu",
                    calibration_session=False)
    return out


def lab_collection(demo: Path, lab: Path) -> Path:
    """A collection folder as a lab has it, from a demo study: two frame folders, two MayaCam
    files, one CT per bone (talus, calcaneus)."""
    for cam in ("cam01", "cam02"):
        shutil.copytree(demo / "frames" / cam, lab / cam)
        (lab / "cams").mkdir(parents=True, exist_ok=True)
        shutil.copy(demo / "rig" / f"{cam}.txt", lab / "cams")
    (lab / "ct").mkdir()
    for bone in ("talus", "calcaneus"):
        shutil.copy(demo / "volumes" / f"{bone}.mha", lab / "ct")
    return lab


def menu_action(win, text: str):
    """The window's menu action titled ``text`` (as a user finds it in the menu bar)."""
    menus = [m.menu() for m in win.menuBar().actions() if m.menu()]
    return next(a for menu in menus for a in menu.actions() if a.text() == text)


def parse_command(argv, command):
    """``argv`` parsed by ``talus COMMAND``'s own argument parser (``app.commands.<command>``)."""
    import argparse

    p = argparse.ArgumentParser()
    command.configure(p)
    return p.parse_args(argv)


def run_command(argv, command, name: str) -> int:
    """``talus NAME argv`` run in this process as the CLI runs it: its exit code, an error reported
    (``app.commands._shared.report_error``) as the CLI reports it."""
    from app.commands._shared import report_error

    a = parse_command(argv, command)
    try:
        return a.run(a)
    except Exception as exc:
        return report_error(exc, name)


def track_options_spy(monkeypatch) -> list:
    """``track_study`` replaced: the options of each call kept in the returned list, nothing tracked."""
    import core.tracking.from_study as from_study

    seen = []

    def fake_track_study(study, trial, bones, frames, *, options, **kw):
        seen.append(options)
        return None, {"summary": {"status": "stopped"}}

    monkeypatch.setattr(from_study, "track_study", fake_track_study)
    return seen
