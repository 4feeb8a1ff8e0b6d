"""Helpers of the batch tests (``from tests.core.tracking.batch_helpers import save_flat_calibration``)."""

from __future__ import annotations

import numpy as np


def save_flat_calibration(folder, trials, *, name: str = "flat.v1") -> str:
    """Point ``trials`` of the study at ``folder`` at a saved calibration version ``name`` that has
    correction pipelines, laid out as ``talus calibrate`` saves one (pipelines under
    ``calibrations/<series>/v<N>``, the manifest's calibration and the settings'
    ``calibration_files`` entry naming them): the trials' own cameras, and per view a flatfield of
    a uniform field at the view's full scale. Tracking then finds the frames flatfield-corrected
    (:func:`core.tracking.from_study.frame_reader`) although they are those divided by the full
    scale. Returns ``name``."""
    from core.imaging.flatfield import Flatfield
    from core.imaging.pipeline import FlatfieldStep, Pipeline
    from core.io.atomic import atomic_write_json
    from core.study import Study
    from core.study.calibrations import use_calibration

    series, version = name.split(".v")
    with Study.open(folder, mode="w") as st:
        entry = st.manifest["trials"][trials[0]]
        cameras = [st.path(c) for c in st.manifest["calibrations"][entry["calibration"]]["cameras"]]
        raw = st.trial(trials[0]).frames(0)
        base = st.folder / "calibrations" / series / f"v{version}"
        base.mkdir(parents=True)
        stored = []
        for k, (frame, view) in enumerate(zip(raw, entry["views"], strict=True)):
            full = float(2 ** int(view.get("bit_depth") or 16) - 1)
            flat = Flatfield(gain=np.full(np.shape(frame), full, np.float32))
            path = base / f"correction_cam{k + 1}.json"
            atomic_write_json(path, Pipeline((FlatfieldStep(flat),)).to_dict())
            stored.append(path.relative_to(st.folder).as_posix())
        st.add_calibration(name, cameras)
        files = dict(st.settings.get("calibration_files", {}))
        files[name] = {"series": series, "version": int(version), "corrections": stored}
        st.update_settings(calibration_files=files)
        for t in trials:
            use_calibration(st, t, name)
    return name
