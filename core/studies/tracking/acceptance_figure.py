"""The acceptance study's figure (:mod:`core.studies.tracking.acceptance`, ``--figure``): per-frame
and low-passed errors of each bone over the trial, the Cramér–Rao bound and the flagged frames
marked. Importable from :mod:`core.studies.tracking.acceptance` as before."""

from __future__ import annotations

import numpy as np

__all__ = ["LEGEND_HEADROOM"]


#: the share of each panel's data range added above it for the legend (:func:`_figure`)
LEGEND_HEADROOM = 0.45


def _figure(errors: dict, filtered: dict, path: str, cfg: dict, bound: dict | None = None,
            flagged: dict | None = None) -> None:
    """Per-frame and filtered errors (``errors``, ``filtered``: bone -> (frames, (n, 6) errors)),
    the flagged frames of the per-frame row marked (``flagged``: bone -> frames)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(2, 2, figsize=(10, 6.4), sharex=True)
    for row, (errs, what) in enumerate(((errors, "per frame"), (filtered, "filtered"))):
        for k, (n, (fr, E)) in enumerate(errs.items()):
            c = f"C{k}"
            et, er = np.linalg.norm(E[:, :3], axis=1), np.linalg.norm(E[:, 3:], axis=1)
            rms = [f"RMS {np.sqrt(np.mean(v ** 2)):.3f}{u}" if len(v) else "no frame"
                   for v, u in ((et, " mm"), (er, "°"))]
            ax[row, 0].plot(fr, et, color=c, lw=1, label=f"{n} ({rms[0]})")
            ax[row, 1].plot(fr, er, color=c, lw=1, label=f"{n} ({rms[1]})")
            marked = [i for i, f in enumerate(fr) if row == 0 and f in set((flagged or {}).get(n, ()))]
            for col, y in ((0, et), (1, er)):  # flagged frames (the checks' or the trajectory pass's)
                ax[row, col].plot(np.asarray(fr)[marked], y[marked], "x", color=c, ms=6)
            if bound and n in bound:  # the least RMS error of any unbiased per-frame estimate
                ax[row, 0].axhline(bound[n]["rms_mm"], color=c, lw=1.2, ls=":")
                ax[row, 1].axhline(bound[n]["rms_deg"], color=c, lw=1.2, ls=":")
        ax[row, 0].set(ylabel=f"centroid error, {what} (mm)")
        ax[row, 1].set(ylabel=f"rotation error, {what} (deg)")
    for a in ax.ravel():
        a.axhline(0.15, color="k", lw=0.8, ls="--")
        a.grid(alpha=0.3)
        lo, hi = a.get_ylim()  # headroom above the curves: the legend covers none of them
        a.set_ylim(lo, hi + LEGEND_HEADROOM * (hi - lo))
        a.legend(fontsize=7, loc="upper right")
    for a in ax[1]:
        a.set(xlabel="frame")
    stage = _stage(cfg)  # on a line of its own: the first is as wide as the figure
    fig.suptitle(f"Synthetic walking trial, {cfg['pixels']}² views, {cfg['voxel_mm']} mm voxels, "
                 f"{cfg['mode']} tracking ({cfg['search']} search), start 5 mm / 5° off, "
                 f"distortion correction: {cfg['correction']}" + (f"\n{stage[2:]}" if stage else "")
                 + f"\nlower row: Butterworth low-pass at {cfg['frame_rate_hz']:.0f} Hz frame rate (dashed: "
                 "0.15 target; dotted: Cramér–Rao bound of a per-frame estimate; x: flagged)", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _stage(cfg: dict) -> str:
    """The title's words for the likelihood final stage, when the run had it (``config.final``)."""
    if cfg.get("final") in (None, "none"):
        return ""
    return f", final stage: {cfg['final']} at {cfg.get('final_highpass_px')} px"
