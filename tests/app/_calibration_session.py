"""One small rendered calibration session per test run, shared by the tests that read it (the
calibration wizard's walk and ``talus calibrate``'s tests); import
``from tests.app._calibration_session import calibration_session``.

384 px (the beads a few pixels wide, as bead localisation needs), seed 0 (the demo trial's rig at
that size), 11 spiral frames (with one excluded by hand, 8 labelled frames are left for the
solve), one grid and one bead-lattice frame, 2 dark and 3 empty-field frames per camera. Its
static cube is labelled in both views, also with poly(4,4) for the first camera's distortion (as
the wizard walk chooses); since beads are searched inside the intensifier's field only, also with 9
or 10 spiral frames or at 320 px (seed 0), which it was not.

The folder is read, never written to (a test that changes it takes a copy). Writing it costs
about 3 s of CPU on the 2-core machine.
"""

from __future__ import annotations

from pathlib import Path

PIXELS = 384
N_SPIRAL = 11
_written: dict[str, Path] = {}


def calibration_session(tmp_path_factory) -> Path:
    """The session folder, written the first time it is asked for in this test run."""
    if "session" not in _written:
        from core.synthetic.session import write_calibration_session

        out = tmp_path_factory.mktemp("calibration_session") / "session"
        write_calibration_session(out, pixels=PIXELS, seed=0, n_spiral=N_SPIRAL, n_grid=1, n_lattice=1,
                                  n_dark=2, n_flat=3)
        _written["session"] = out
    return _written["session"]
