"""The wizard's figures, built off the GUI thread (``matplotlib.figure.Figure``, no pyplot)."""

from __future__ import annotations

import numpy as np

__all__ = ["field_fraction", "reprojection_figure", "rolloff_figure"]


def field_fraction(ff, level: float = 0.1) -> float:
    """Fraction of the image inside the intensifier's field: fluence surface above ``level`` of
    its peak (outside it the surface is noise)."""
    g = np.asarray(ff.gain, float)
    return float(np.mean(g > level * np.percentile(g[np.isfinite(g)], 99)))


def _fig(w: float, h: float):
    from matplotlib.figure import Figure

    return Figure(figsize=(w, h), dpi=90)


def rolloff_figure(flatfields, names) -> object:
    """Radial roll-off of every camera's fluence surface (gain against distance from the centre)."""
    fig = _fig(5.2, 3.2)
    ax = fig.add_subplot(1, 1, 1)
    for c, (ff, name) in enumerate(zip(flatfields, names, strict=True)):
        g = np.asarray(ff.gain, float)
        h, w = g.shape
        yy, xx = np.mgrid[0:h, 0:w]
        r = np.hypot(xx - (w - 1) / 2, yy - (h - 1) / 2)
        ok = np.asarray(ff.valid, bool) & np.isfinite(g)
        bins = np.linspace(0, r.max(), 40)
        k = np.digitize(r[ok], bins)
        prof = [np.median(g[ok][k == i]) if np.any(k == i) else np.nan for i in range(1, len(bins))]
        ax.plot(bins[1:], np.asarray(prof) / np.nanmax(prof), linestyle=("-", "--", ":", "-.")[c % 4],
                linewidth=1.6,
                label=f"{name} ({100 * field_fraction(ff):.0f} % of the image inside the field)")
    ax.set_xlabel("distance from the image centre (px)")
    ax.set_ylabel("relative fluence")
    ax.set_title("Flatfield roll-off", fontsize=9)
    ax.legend(fontsize=7)
    fig.tight_layout()
    return fig


def reprojection_figure(cal) -> object:
    """Reprojection RMS per labelled frame of the bundle adjustment."""
    ba = cal.bundle
    err = ba.errors_px
    n = int(ba.frame_index.max()) + 1 if ba.frame_index.size else 0
    per = [np.sqrt(np.mean(err[ba.frame_index == f] ** 2)) if np.any(ba.frame_index == f) else np.nan
           for f in range(n)]
    fig = _fig(6.0, 4.2)
    ax = fig.add_subplot(1, 1, 1)
    ax.bar(np.arange(n), per, color="tab:blue")
    ax.set_xlabel("labelled frame (the last is the static object when there is one)")
    ax.set_ylabel("RMS reprojection (px)")
    ax.set_title(f"Bundle adjustment: {ba.rms_px:.3f} px RMS, {int(ba.outliers.sum())} outliers", fontsize=9)
    fig.tight_layout()
    return fig
