"""Review-docks cost benchmark (``talus bench review``): GUI-thread time per tracked frame.

While tracking runs, every finished (bone, frame) reaches the GUI thread as one result: the review
data takes it (:meth:`app.review.ReviewData.apply_result`), the frame table updates its row, the
timeline its strip cell, and the plots dock redraws its curves (coalesced to one redraw per
``refresh_ms`` in the window; here, the worst case, **one redraw per frame**). This benchmark times
exactly that on the GUI thread — result handling, the plots' redraw and the repaint of both docks
(``QWidget.repaint``, so the paint really happens inside the timed span) — for a trial of
``--frames`` frames of the demo's bones (its rig and CTs; poses: the demo's ground-truth motion
resampled to the trial length, which only benchmarks may read). Prints JSON: per-frame times
(median, 95th percentile, max, ms) of each part and in all, the machine, the sizes.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

__all__ = ["main", "run_review_benchmark"]


def _resample(P: np.ndarray, n: int) -> np.ndarray:
    """``(m, 4, 4)`` poses resampled to ``n`` frames (translation linear, rotation slerp)."""
    from scipy.spatial.transform import Rotation, Slerp

    t_old = np.linspace(0, 1, len(P))
    t_new = np.linspace(0, 1, n)
    out = np.tile(np.eye(4), (n, 1, 1))
    out[:, :3, :3] = Slerp(t_old, Rotation.from_matrix(P[:, :3, :3]))(t_new).as_matrix()
    for k in range(3):
        out[:, k, 3] = np.interp(t_new, t_old, P[:, k, 3])
    return out


def run_review_benchmark(*, frames: int = 300, folder: str | Path | None = None, pixels: int = 64,
                         refresh_every: int = 1, size=(1920, 1080)) -> dict:
    from PySide6 import QtCore, QtWidgets

    from core.synthetic.demo import make_demo_study

    from .model import ViewerModel
    from .plots import PlotsDock
    from .review import FrameTableDock, ReviewData
    from .session import open_study
    from .timeline import Timeline

    app = QtWidgets.QApplication.instance() or QtWidgets.QApplication(sys.argv[:1])
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(folder) if folder else Path(tmp) / "demo"
        if not (path / "study.json").is_file():
            make_demo_study(path, n_frames=4, pixels=pixels, seed=0, device="cpu", spacing=2.0,
                            tissue_spacing=8.0, calibration_session=False)
        session = open_study(path, read_only=True)
        session.close()
        truth = {layer.name: np.load(path / "poses" / f"{layer.name}.npy") for layer in session.model.layers}
    src = session.model
    model = ViewerModel(src.rig, frames)
    poses = {}
    for layer in src.layers:
        poses[layer.name] = _resample(truth[layer.name], frames)
        model.add_bone(layer.name, layer.volume, poses[layer.name][0])
    # the review docks and the timeline as the window lays them out (no overlays, no 3-D scene:
    # only what follows the tracking results)
    win = QtWidgets.QMainWindow()
    win.resize(*size)
    timeline = Timeline(model)
    win.setCentralWidget(timeline)
    names = [layer.name for layer in model.layers]
    data = ReviewData(names, frames)
    table = FrameTableDock(data, model)
    plots = PlotsDock(data, model)
    for title, w in (("Frames", table), ("Plots", plots)):
        dock = QtWidgets.QDockWidget(title, win)
        dock.setWidget(w)
        win.addDockWidget(QtCore.Qt.DockWidgetArea.RightDockWidgetArea, dock)

    def strip(_b: int, f: int) -> None:  # as app.review_actions keeps the timeline in step
        code = data.frame_status_at(f)
        if timeline.status[f] != code:
            timeline.status[f] = code
            timeline.refresh_status()

    data.changed.connect(strip)
    win.show()
    app.processEvents()
    rng = np.random.default_rng(0)
    t_apply, t_plot, t_paint, t_paint_plots = [], [], [], []
    for f in range(frames):
        for b in names:
            flags = ["score below 0.85 x the recent median"] if rng.random() < 0.03 else []
            res = {"bone": b, "frame": f, "score": float(0.8 + 0.1 * rng.random()), "flags": flags,
                   "confidence": {"translation_mm": 0.05, "rotation_deg": 0.1}}
            t0 = time.perf_counter()
            data.apply_result(res, poses[b][f])
            t_apply.append(time.perf_counter() - t0)
        if (f + 1) % refresh_every == 0:
            t0 = time.perf_counter()
            plots.refresh()
            t1 = time.perf_counter()
            plots.canvases[plots.page].viewport().repaint()
            t2 = time.perf_counter()
            table.view.viewport().repaint()
            timeline.strip.repaint()
            t3 = time.perf_counter()
            t_plot.append(t1 - t0)
            t_paint.append(t3 - t1)
            t_paint_plots.append(t2 - t1)
        app.processEvents()
    n_b = len(names)
    per_frame_apply = np.add.reduceat(np.array(t_apply), np.arange(0, len(t_apply), n_b))
    all_ms = 1e3 * (per_frame_apply[:len(t_plot)] + np.array(t_plot) + np.array(t_paint))
    win.close()

    def stats(a) -> dict:
        a = np.asarray(a, float)
        return {"median": float(np.median(a)), "p95": float(np.percentile(a, 95)), "max": float(a.max())}

    return {"benchmark": "review", "frames": frames, "bones": names, "window": list(size),
            "refresh_every_frames": refresh_every, "plots": len(plots.plots),
            "table_rows": table.table_model.rowCount(),
            "ms_per_frame": {"results_to_table_and_timeline": stats(1e3 * per_frame_apply),
                             "plots_redraw": stats(1e3 * np.array(t_plot)),
                             "repaint_docks": stats(1e3 * np.array(t_paint)),
                             "repaint_plots_only": stats(1e3 * np.array(t_paint_plots)),
                             "total": stats(all_ms)},
            "total_within_10ms_median": bool(np.median(all_ms) <= 10.0),
            "machine": {"platform": platform.platform(), "cpu_count": os.cpu_count(),
                        "python": platform.python_version(),
                        "load_average": list(os.getloadavg()) if hasattr(os, "getloadavg") else None}}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="talus bench review", description=__doc__.split("\n\n")[0])
    ap.add_argument("--frames", type=int, default=300, help="trial length (default 300)")
    ap.add_argument("--refresh-every", type=int, default=1,
                    help="redraw the plots every N frames (default 1: the worst case)")
    ap.add_argument("--out", metavar="FILE", help="also write the JSON to FILE")
    a = ap.parse_args(argv)
    if a.frames < 2 or a.refresh_every < 1:
        ap.error("--frames: at least 2; --refresh-every: at least 1")
    if sys.platform.startswith("linux") and not os.environ.get("DISPLAY"):
        os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")
    result = run_review_benchmark(frames=a.frames, refresh_every=a.refresh_every)
    text = json.dumps(result, indent=2)
    print(text)
    if a.out:
        from core.io.atomic import atomic_write

        atomic_write(a.out, text + "\n")
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
