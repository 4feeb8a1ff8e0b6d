"""The report of a session calibration: JSON figures of merit and figures (matplotlib, Agg).

* :func:`session_report` — the JSON-ready dict kept in :attr:`SessionCalibration.report`:
  per camera the flatfield, the distortion model table (cross-validated error of every candidate),
  the grid residuals (px and mm), the veiling glare measured from the lead-disc frames (or None);
  per frame and per bead the reprojection error; the rig with its
  parameter standard deviations; the predicted 3-D reconstruction error over the capture volume
  (beads localised with the adjustment's own reprojection error, triangulated by the rig:
  :func:`core.calibration.errormap.capture_lattice`); notes and the time of every step.
* :func:`write_report` — that JSON plus the figures into a folder: grid residual vectors and the
  model table, reprojection error per frame and per bead, the 3-D error map, parameter SDs.

Lengths in mm, pixels ``(u, v) = (column, row)``.
"""

from __future__ import annotations

import json
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from ._session_frames import lit_field
from .errormap import capture_lattice, reconstruction_errors

__all__ = ["session_report", "write_report"]


def _f(x):
    if x is None:
        return None
    x = float(x)
    return x if np.isfinite(x) else None


def _camera(c, std) -> dict:
    d = {"name": c.name, "fx_px": c.fx, "fy_px": c.fy, "cu_px": c.cu, "cv_px": c.cv,
         "pixel_size_mm": c.pixel_size, "sid_mm": c.sid if c.pixel_size else None,
         "source_mm": c.source.tolist(), "width": c.width, "height": c.height}
    d["std"] = {"f_px": _f(std["f"]), "cu_px": _f(std["cu"]), "cv_px": _f(std["cv"]),
                "source_mm": [_f(v) for v in std["source"]], "sid_mm": _f(std.get("sid"))}
    return d


def error_volume(rig, noise_px: float, *, spacing_mm: float = 20.0, draws: int = 20, rng=0) -> dict:
    """Reconstruction error over the capture volume of beads localised to ``noise_px``:
    lattice points (``spacing_mm``) in every cone, projected by ``rig``, noise added, triangulated."""
    X = capture_lattice(rig, spacing_mm=spacing_mm, margin_px=10.0)
    if len(X) == 0:
        return {"n_points": 0}
    e = reconstruction_errors(rig, [rig] * int(draws), X, image_noise_px=float(noise_px), rng=rng)
    rms = np.sqrt(np.mean(e**2, axis=0))
    return {"spacing_mm": spacing_mm, "noise_px": float(noise_px), "n_points": len(X), "draws": int(draws),
            "rms_mm": float(np.sqrt(np.mean(e**2))), "p95_mm": float(np.percentile(rms, 95)),
            "max_point_rms_mm": float(rms.max()), "points_mm": X.tolist(), "point_rms_mm": rms.tolist()}


def session_report(cal, *, notes=(), dlt=(), seconds=None, manifest=None, lattice=None) -> dict:
    """The JSON-ready report of a :class:`~core.calibration.session.SessionCalibration`."""
    ba = cal.bundle
    cams = []
    for c in cal.cameras:
        g = c.grid
        cams.append({
            "name": c.name, "kv": c.kv,
            "flatfield": {"method": c.flatfield.method, "kernel_px": c.flatfield.kernel_size,
                          "frames": c.flatfield.n_frames, "invalid_pixels": c.flatfield.n_invalid,
                          "edge_to_centre": _f(np.percentile(c.flatfield.gain[lit_field(c.flatfield)], 2)
                                               / np.percentile(c.flatfield.gain, 99.5))},  # in the field
            "distortion": {"model": g.spec.label, "n_params": g.model.n_params,
                           "grid_frames": g.n_frames, "placements": g.n_placements,
                           "points": len(g.ideal_uv), "mm_per_px": g.mm_per_px,
                           "residuals": g.residuals.to_dict(),
                           "table": [{k: (_f(v) if isinstance(v, float) else v) for k, v in r.items()}
                                     for r in g.table],
                           "notes": list(g.notes)},
            "lattice_check": (lattice or {}).get(c.name),
            "glare": (None if getattr(c, "glare", None) is None
                      else c.glare.to_dict(pixel_mm=g.mm_per_px)),
        })
    err = ba.errors_px
    per_bead = {}
    n_main = len(cal.observations) - (cal.static_target is not None)
    for b in range(len(cal.target)):
        sel = (ba.point_index == b) & (ba.frame_index < n_main) & ~ba.outliers
        if sel.any():
            per_bead[cal.target.bead_ids[b]] = _f(np.sqrt(np.mean(err[sel] ** 2)))
    vol = error_volume(cal.rig, max(ba.rms_px, 0.01))
    rep = {
        "cameras": cams,
        "object": cal.target.name,
        "static_object": None if cal.static_target is None else cal.static_target.name,
        "frames": cal.frames,
        "n_frames_labelled": sum(1 for f in cal.frames if f["ok"]),
        "bundle": {"rms_px": ba.rms_px, "rms_all_px": ba.rms_all_px, "sigma0": _f(ba.sigma0),
                   "observations": len(ba.frame_index), "outliers": int(ba.outliers.sum()),
                   "evaluations": ba.n_evaluations, "message": ba.message,
                   "per_bead_rms_px": per_bead,
                   "per_view_rms_px": [_f(np.sqrt(np.mean(err[(ba.view == v) & ~ba.outliers] ** 2)))
                                       for v in range(len(cal.rig))]},
        "dlt_start": list(dlt),
        "rig": [_camera(c, s) for c, s in zip(cal.rig, ba.camera_std, strict=True)],
        "view_angle_deg": float(np.degrees(cal.rig.angle_between_views())),
        "error_volume": {k: v for k, v in vol.items() if k not in ("points_mm", "point_rms_mm")},
        "notes": list(notes) + [n for c in cal.cameras for n in c.grid.notes],
        "seconds": dict(seconds or {}),
    }
    if manifest:
        rep["session"] = {k: manifest[k] for k in ("name", "date", "cameras", "bit_depth") if k in manifest}
    rep["_error_volume_points"] = vol
    return rep


@contextmanager
def _figure(path: Path, figsize, *, rows: int = 1, cols: int = 1, projection: str | None = None):
    """``(fig, axes)`` of a new Agg figure (``dpi`` 100), laid out tightly and saved to ``path``
    when the block ends. A :class:`matplotlib.figure.Figure` on its own Agg canvas, not pyplot:
    nothing global (pyplot's figure list, the backend) is touched, so a worker thread of the
    window (the calibration wizard saves from one) can write the report."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=figsize, dpi=100)
    FigureCanvasAgg(fig)
    axes = fig.subplots(rows, cols) if projection is None else fig.add_subplot(projection=projection)
    yield fig, axes
    fig.tight_layout()
    fig.savefig(path)


def _grid_figure(cal, path: Path) -> Path:
    n = len(cal.cameras)
    with _figure(path, (6 * n, 6.2), cols=n) as (_, axes):
        for ax, c in zip(np.atleast_1d(axes), cal.cameras, strict=True):
            g = c.grid
            r = g.model.inverse(g.distorted_uv) - g.ideal_uv
            scale = 0.5 * np.median(np.linalg.norm(np.diff(g.ideal_uv[:2], axis=0))) / max(
                np.percentile(np.linalg.norm(r, axis=1), 99), 1e-6)
            ax.quiver(g.ideal_uv[:, 0], g.ideal_uv[:, 1], r[:, 0], r[:, 1], np.linalg.norm(r, axis=1),
                      angles="xy", scale_units="xy", scale=1 / scale, cmap="viridis")
            ax.set_aspect("equal")
            ax.invert_yaxis()
            st = g.residuals.to_dict()["mm"]
            ax.set_title(f"{c.name}: {g.spec.label}, grid residual RMS {st['rms']:.3f} mm "
                         f"(max {st['max']:.3f})\narrows × {scale:.0f}", fontsize=9)
            ax.set_xlabel("u (px)")
            ax.set_ylabel("v (px)")
    return path


def _table_figure(cal, path: Path) -> Path:
    rows = []
    for c in cal.cameras:
        for r in c.grid.table:
            cv = r.get("rms_mm")
            rows.append([c.name, r["model"], "—" if cv is None or not np.isfinite(cv) else f"{cv:.4f}",
                         "chosen" if r["model"] == c.grid.spec.label else ""])
    if not rows:
        rows = [[c.name, c.grid.spec.label, "(given)", "chosen"] for c in cal.cameras]
    with _figure(path, (7, 0.3 * len(rows) + 1.0)) as (_, ax):
        ax.axis("off")
        t = ax.table(cellText=rows, colLabels=["camera", "model", "5-fold CV RMS (mm)", ""], loc="center")
        t.auto_set_font_size(False)
        t.set_fontsize(8)
        ax.set_title("Distortion models: cross-validated error on held-out grid points", fontsize=9)
    return path


def _reprojection_figure(cal, path: Path) -> Path:
    ba = cal.bundle
    err = ba.errors_px
    F = int(ba.frame_index.max()) + 1 if ba.frame_index.size else 0
    per_frame = [np.sqrt(np.mean(err[(ba.frame_index == f) & ~ba.outliers] ** 2))
                 if np.any((ba.frame_index == f) & ~ba.outliers) else np.nan for f in range(F)]
    nb = len(cal.target)
    sel_t = ba.frame_index < len(cal.observations) - (cal.static_target is not None)
    per_bead = [np.sqrt(np.mean(err[(ba.point_index == b) & sel_t & ~ba.outliers] ** 2))
                if np.any((ba.point_index == b) & sel_t & ~ba.outliers) else np.nan for b in range(nb)]
    with _figure(path, (9, 6), rows=2) as (_, (a1, a2)):
        a1.bar(np.arange(F), per_frame, color="tab:blue")
        a1.set_xlabel("labelled frame (the last is the static object when there is one)")
        a1.set_ylabel("RMS reprojection error (px)")
        a1.set_title(f"Bundle adjustment: {ba.rms_px:.3f} px RMS over {len(err)} observations, "
                     f"{int(ba.outliers.sum())} outliers", fontsize=9)
        a2.bar(np.arange(nb), per_bead, color="tab:orange")
        a2.set_xticks(np.arange(nb), cal.target.bead_ids, rotation=90, fontsize=6)
        a2.set_ylabel(f"RMS per bead of {cal.target.name} (px)")
    return path


def _volume_figure(cal, vol: dict, path: Path) -> Path:
    X = np.asarray(vol.get("points_mm", []))
    e = np.asarray(vol.get("point_rms_mm", []))
    with _figure(path, (7, 6), projection="3d") as (fig, ax):
        if len(X):
            sc = ax.scatter(X[:, 0], X[:, 1], X[:, 2], c=e, cmap="magma", s=6)
            fig.colorbar(sc, ax=ax, shrink=0.6, label="RMS reconstruction error (mm)")
        for c in cal.rig:
            ax.scatter(*c.source, color="k", marker="*", s=60)
        ax.set_xlabel("x (mm)")
        ax.set_ylabel("y (mm)")
        ax.set_zlabel("z (mm)")
        ax.set_title(f"3-D reconstruction error over the capture volume\n(beads localised to "
                     f"{vol.get('noise_px', 0):.3f} px; RMS {vol.get('rms_mm', float('nan')):.4f} mm)",
                     fontsize=9)
    return path


def _sd_figure(cal, path: Path) -> Path:
    ba = cal.bundle
    names = ["f (px)", "cu (px)", "cv (px)", "source x", "source y", "source z", "SID"]
    w = 0.8 / len(cal.rig)
    with _figure(path, (8, 4)) as (_, ax):
        for v, (c, s) in enumerate(zip(cal.rig, ba.camera_std, strict=True)):
            vals = [s["f"], s["cu"], s["cv"], *s["source"], s.get("sid", np.nan)]
            ax.bar(np.arange(len(names)) + v * w, vals, w, label=c.name)
        ax.set_xticks(np.arange(len(names)) + 0.4 - w / 2, names)
        ax.set_ylabel("standard deviation (px or mm)")
        ax.set_title("Parameter standard deviations from the bundle adjustment", fontsize=9)
        ax.legend()
    return path


def write_report(cal, folder) -> dict:
    """Write ``report.json`` and the PNG figures of ``cal`` into ``folder``; returns the paths."""
    from ..io.atomic import atomic_write_json

    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    rep = {k: v for k, v in cal.report.items() if not k.startswith("_")}
    vol = cal.report.get("_error_volume_points") or {}
    figs = {"grid_residuals": _grid_figure(cal, out / "grid_residuals.png"),
            "model_table": _table_figure(cal, out / "distortion_models.png"),
            "reprojection": _reprojection_figure(cal, out / "reprojection_errors.png"),
            "error_volume": _volume_figure(cal, vol, out / "error_volume.png"),
            "parameter_sd": _sd_figure(cal, out / "parameter_sd.png")}
    rep["figures"] = {k: p.name for k, p in figs.items()}
    atomic_write_json(out / "report.json", json.loads(json.dumps(rep, default=_f)))
    return {"report": out / "report.json", **figs}
