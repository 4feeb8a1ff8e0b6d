"""The 30-frame demo walk in 48² views that the batch tests track, built once per test process
(``from tests.core.tracking.demo_walk import built, copy_keyed``).

tests/core/tracking's ``demo_walk_48`` and ``keyed``, tests/app/test_cli_batch.py's ``demo`` and
tests/app/test_app_batch_pass.py's ``keyed_folder`` each built it before. :func:`built` builds it
the first time a process asks and gives the same folder after; the fixtures copy it where they
write. It is a function, not a session fixture, so the files that use it are not tied to one
xdist group (tests/conftest.py): a worker that runs any of them builds it once (about 1 s on the
2-core test machine once Warp's kernels are compiled)."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np

#: the keyframe that :func:`copy_keyed` sets by hand: two ranges, 12 back to 0 and 12 on to 29
KEY_FRAME = 12

_built: dict[str, Path] = {}


def built(tmp_path_factory) -> Path:
    """The demo study (read it, or copy it before writing): the 30-frame walk in 48² views, 3 mm
    bone and 6 mm tissue voxels, no calibration session; every bone has its true pose at frame 0
    as a keyframe (the bones move little from frame to frame). Built in this process's first
    caller's session temporary folder."""
    if "walk" not in _built or not (_built["walk"] / "poses").is_dir():
        from core.synthetic import make_demo_study

        out = tmp_path_factory.mktemp("demo_walk_48") / "demo"
        make_demo_study(out, n_frames=30, pixels=48, spacing=3.0, tissue_spacing=6.0, device="cpu",
                        calibration_session=False)
        _built["walk"] = out
    return _built["walk"]


def copy_keyed(tmp_path_factory, dest: Path, bone: str = "talus") -> Path:
    """A copy of :func:`built` at ``dest`` whose ``bone`` has one hand-set keyframe,
    :data:`KEY_FRAME` (frame 0's cleared): two ranges, 12 back to 0 and 12 on to 29, both tracking
    frame 12. Returns ``dest``."""
    from core.study import Study

    out = Path(shutil.copytree(built(tmp_path_factory), dest))
    truth = np.load(out / "poses" / f"{bone}.npy")
    with Study.open(out, mode="w") as st:
        t = st.trial("walk")
        t.clear_pose(bone, 0)
        t.record_pose(bone, KEY_FRAME, truth[KEY_FRAME])
    return out
