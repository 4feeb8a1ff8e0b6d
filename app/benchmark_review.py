"""Review-docks cost benchmark (``talus bench review``): GUI-thread time per tracked frame.

While tracking runs, every finished (bone, frame) reaches the GUI thread as one result: the review
data takes it (:meth:`app.review.ReviewData.apply_result`), the frame table updates its row, the
timeline its strip cell, and the plots dock marks the bone changed; its redraw is coalesced to one
per ``refresh_ms`` in the window. This benchmark times, on the GUI thread, for a trial of
``--frames`` frames of the demo's bones (its rig and CTs; poses: the demo's ground-truth motion
resampled to the trial length, which only benchmarks may read), **with one redraw per frame** (the
worst case: frames slower than the redraw rate, as on a CPU):

* ``results_to_table_and_timeline``: the results of one frame (every bone) handed over;
* ``plots_redraw``: the plots dock's redraw of the page shown (curves of the changed bones);
* ``paint``: the event loop until the window has painted what changed (plots, table row,
  timeline cell — Qt repaints only the regions marked dirty): the time spent inside
  ``processEvents`` calls, until the plots' canvas has painted;
* ``total``: the three together, per frame;

and, for reference, ``repaint_plots_full``: a full repaint of the plots' canvas (what an expose
or a resize costs), and the cost per frame amortised over the redraw rate at a few tracking rates
(computed from the medians). Each time is taken on two clocks: the GUI thread's CPU time
(``time.thread_time``: the cost, comparable on a shared machine) and the wall clock (which on a
loaded machine adds the wait for a core). The docks are laid out as in the window (the frame
table on the right, a quarter of the width; the plots along the bottom, a third of the height);
work the docks hand to their own worker threads (the low-pass of the dashed curves) is not GUI
time and is not counted, the drawing of its answer is. ``--repeat N`` runs it N times and reports
the run with the median total, with every run's medians and load average. Prints JSON: per-frame
times (median, 95th percentile, max, ms), the machine, the sizes.
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


def _now() -> np.ndarray:
    """(CPU time of this thread, wall time), seconds."""
    return np.array([time.thread_time(), time.perf_counter()])


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
    # as app.review_actions lays them out: the table on the right over the whole height (a quarter
    # of the width), the plots along the bottom (a third of the height)
    Area = QtCore.Qt.DockWidgetArea
    win.setCorner(QtCore.Qt.Corner.BottomRightCorner, Area.RightDockWidgetArea)
    win.setCorner(QtCore.Qt.Corner.TopRightCorner, Area.RightDockWidgetArea)
    docks = {}
    for title, w, area in (("Frames", table, Area.RightDockWidgetArea),
                           ("Plots", plots, Area.BottomDockWidgetArea)):
        docks[title] = dock = QtWidgets.QDockWidget(title, win)
        dock.setWidget(w)
        win.addDockWidget(area, dock)
    win.resizeDocks([docks["Frames"]], [max(340, size[0] // 4)], QtCore.Qt.Orientation.Horizontal)
    win.resizeDocks([docks["Plots"]], [max(220, size[1] // 3)], QtCore.Qt.Orientation.Vertical)

    def strip(_b: int, f: int) -> None:  # as app.review_actions keeps the timeline in step
        code = data.frame_status_at(f)
        if timeline.status[f] != code:
            timeline.status[f] = code
            timeline.refresh_status()

    data.changed.connect(strip)
    win.show()
    for _ in range(5):
        app.processEvents()
    canvas = plots.canvases[plots.page]
    canvas_size = [canvas.width(), canvas.height()]
    painted = []

    class PaintSeen(QtCore.QObject):
        def eventFilter(self, obj, event):  # Qt's name: notes that the canvas painted
            if event.type() == QtCore.QEvent.Type.Paint:
                painted.append(1)
            return False

    seen = PaintSeen(canvas)
    canvas.viewport().installEventFilter(seen)

    def until_painted() -> np.ndarray:
        """(CPU, wall) seconds spent in ``processEvents`` until the plots' canvas painted (at most
        ~1 s of waiting in all)."""
        painted.clear()
        spent = np.zeros(2)
        deadline = time.perf_counter() + 1.0
        while not painted and time.perf_counter() < deadline:
            t0 = _now()
            app.processEvents()
            spent += _now() - t0
            if not painted:
                time.sleep(0.001)  # Qt asks for the repaint on a short timer
        t0 = _now()
        app.processEvents()  # what the same paint left posted
        return spent + _now() - t0

    rng = np.random.default_rng(0)
    t_apply, t_plot, t_paint = [], [], []  # (CPU, wall) seconds each
    for f in range(frames):
        t_frame = np.zeros(2)
        for b in names:
            flags = ["score below 0.85 x the recent median"] if rng.random() < 0.03 else []
            res = {"bone": b, "frame": f, "score": float(0.8 + 0.1 * rng.random()), "flags": flags,
                   "confidence": {"translation_mm": 0.05, "rotation_deg": 0.1}}
            t0 = _now()
            data.apply_result(res, poses[b][f])
            t_frame += _now() - t0
        t_apply.append(t_frame)
        if (f + 1) % refresh_every == 0:
            t0 = _now()
            plots.refresh()
            t_plot.append(_now() - t0)
            t_paint.append(until_painted())
    t_full = []
    for _ in range(10):
        t0 = _now()
        canvas.viewport().repaint()
        t_full.append(_now() - t0)
    t_apply, t_plot, t_paint, t_full = (1e3 * np.array(a) for a in (t_apply, t_plot, t_paint, t_full))
    per = t_apply[refresh_every - 1::refresh_every][:len(t_plot)] + t_plot + t_paint
    win.close()

    def stats(a) -> dict:
        a = np.asarray(a, float)
        return {"median": float(np.median(a)), "p95": float(np.percentile(a, 95)), "max": float(a.max())}

    def both(a) -> dict:
        return {"cpu": stats(a[:, 0]), "wall": stats(a[:, 1])}

    apply_ms = float(np.median(t_apply[:, 0]))
    redraw_ms = float(np.median(t_plot[:, 0] + t_paint[:, 0]))
    rate_hz = 1000.0 / plots._timer.interval()
    amortised = {f"{fps:g}_frames_per_s": apply_ms + redraw_ms * min(1.0, rate_hz / fps)
                 for fps in (1, 10, 26, 100)}
    return {"benchmark": "review", "frames": frames, "bones": names, "window": list(size),
            "refresh_every_frames": refresh_every, "plots": len(plots.plots),
            "layout": "the frame table on the right (a quarter of the width), the plots dock along the "
                      "bottom (a third of the height), the timeline in the centre",
            "plots_canvas_px": canvas_size, "plots_page": plots.page,
            "table_rows": table.table_model.rowCount(),
            "redraws_per_s_at_most": rate_hz,
            "clocks": "cpu: the GUI thread's CPU time (time.thread_time); wall: elapsed time, which on a "
                      "loaded machine includes waiting for a core",
            "ms_per_frame": {"results_to_table_and_timeline": both(t_apply), "plots_redraw": both(t_plot),
                             "paint": both(t_paint), "total": both(per)},
            "repaint_plots_full_ms": both(t_full),
            "ms_per_frame_cpu_amortised_by_tracking_rate": amortised,
            "total_cpu_within_10ms_median": bool(np.median(per[:, 0]) <= 10.0),
            "qt_platform": app.platformName(),
            "machine": {"platform": platform.platform(), "cpu_count": os.cpu_count(),
                        "python": platform.python_version(),
                        "load_average": list(os.getloadavg()) if hasattr(os, "getloadavg") else None}}


def main(argv: list[str] | None = None, *, prog: str = "python -m app.benchmark_review") -> int:
    """Parse ``argv`` and run; ``prog`` is the name the usage shows (``talus bench review`` passes
    its own)."""
    ap = argparse.ArgumentParser(prog=prog, description=__doc__.split("\n\n")[0])
    ap.add_argument("--frames", type=int, default=300, help="trial length (default 300)")
    ap.add_argument("--refresh-every", type=int, default=1,
                    help="redraw the plots every N frames (default 1: the worst case)")
    ap.add_argument("--repeat", type=int, default=1,
                    help="run N times (default 1) and report the run with the median total GUI-thread CPU "
                         "time per frame, with every run's medians and load average")
    ap.add_argument("--out", metavar="FILE", help="also write the JSON to FILE")
    a = ap.parse_args(argv)
    if a.frames < 2 or a.refresh_every < 1 or a.repeat < 1:
        ap.error("--frames: at least 2; --refresh-every, --repeat: at least 1")
    if sys.platform.startswith("linux") and not os.environ.get("DISPLAY"):
        os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")
    with tempfile.TemporaryDirectory() as tmp:
        runs = [run_review_benchmark(frames=a.frames, refresh_every=a.refresh_every,
                                     folder=Path(tmp) / "demo") for _ in range(a.repeat)]
    order = sorted(range(len(runs)), key=lambda k: runs[k]["ms_per_frame"]["total"]["cpu"]["median"])
    result = runs[order[(len(runs) - 1) // 2]]
    if a.repeat > 1:
        result["repeats"] = [{"cpu_median_ms": {k: v["cpu"]["median"] for k, v in r["ms_per_frame"].items()},
                              "load_average": r["machine"]["load_average"]} for r in runs]
    text = json.dumps(result, indent=2)
    print(text)
    if a.out:
        from core.io.atomic import atomic_write

        atomic_write(a.out, text + "\n")
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
