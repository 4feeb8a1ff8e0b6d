"""A one-page trial report (``talus report``, *File → Export… → Trial report*): HTML or PDF.

:func:`trial_summary` gathers, from the study alone (nothing of a synthetic generator's truth):

* the **calibration**: the trial's calibration, its saved version's quality (bundle-adjustment
  reprojection RMS, frames, observations) and its warnings (a lab frame not the static cube's)
  when :mod:`core.study.calibrations` saved it, and per camera the image size, focal length and
  source–image distance;
* the **tracking**: per bone the frames tracked, flagged, keyframes and hand-edited, the median
  score and per-frame confidence σ (mm, °), and the last tracking run's summary (status, time per
  frame) from the study's tracking report;
* the **flagged frames** with their reasons;
* **kinematics**: the joints' Grood–Suntay angles (:mod:`core.tracking.jcs`, principal-axes
  anatomical frames).

:func:`write_report` renders it with matplotlib's Agg backend (no window): an HTML page with the
figures embedded as PNG, or a one-page A4 PDF (``PdfPages``). Written atomically.
Frame numbers are 0-based.
"""

from __future__ import annotations

import base64
import html
import io
import os
from pathlib import Path

import numpy as np

__all__ = ["trial_summary", "write_report"]


def _median(a) -> float | None:
    a = np.asarray(a, float)
    a = a[np.isfinite(a)]
    return float(np.median(a)) if a.size else None


def _calibration(study, trial) -> dict:
    out: dict = {"name": trial.calibration}
    try:
        from .calibrations import calibration_versions

        for v in calibration_versions(study):
            if v["name"] == trial.calibration and v.get("folder"):
                import json

                cal_file = study.folder / v["folder"] / "calibration.json"
                doc = json.loads(cal_file.read_text(encoding="utf-8"))
                out["quality"] = doc.get("quality")
                out["created"] = v.get("created")
                report = study.folder / v["folder"] / "report" / "report.json"
                if report.is_file():  # e.g. a lab frame not the cube's: every pose is in that frame
                    saved = json.loads(report.read_text(encoding="utf-8"))
                    out["warnings"] = list(saved.get("warnings") or [])
    except (OSError, ValueError, KeyError):  # a study without saved versions: the rig is enough
        pass
    cams = []
    for cam in trial.rig():
        h, w = cam.image_shape
        ps = getattr(cam, "pixel_size", None)
        cams.append({"name": cam.name, "image_px": [int(w), int(h)], "focal_px": float(cam.fx),
                     "sid_mm": float(cam.fx * ps) if ps else None})
    out["cameras"] = cams
    return out


def trial_summary(study, trial_name: str) -> dict:
    """Everything the report shows, as plain data (see the module docs)."""
    from ..tracking.jcs import anatomical_frames, default_joints, joint_series, volume_points

    trial = study.trial(trial_name)
    n = trial.n_frames
    bones, flagged, poses = [], [], {}
    for b in trial.bones:
        st = trial.results(b)
        poses[b] = st.poses(n)
        tracked = {f: r for f, r in st.records.items() if r.pose is not None and r.kind == "tracked"}
        done = st.done
        edited = [f for f, r in done.items() if r.kind == "hand"]
        sig_t, sig_r, flags = [], [], []
        for f, r in sorted(tracked.items()):
            conf = (r.tracking or {}).get("confidence") or {}
            sig_t.append(conf.get("translation_mm") if conf.get("translation_mm") is not None else np.nan)
            sig_r.append(conf.get("rotation_deg") if conf.get("rotation_deg") is not None else np.nan)
            why = (r.tracking or {}).get("flags") or []
            if why:
                flags.append(f)
                flagged.append({"bone": b, "frame": int(f), "reasons": list(why), "score": r.score})
        bones.append({"bone": b, "tracked": len(tracked), "flagged": len(flags),
                      "keyframes": len(st.keyframes), "edited": len(edited),
                      "median_score": _median([r.score for r in tracked.values()]),
                      "median_sigma_mm": _median(sig_t), "median_sigma_deg": _median(sig_r)})
    run = None
    if trial_name in study.report_names("tracking"):
        rep = study.read_report("tracking", trial_name)
        run = rep.get("summary")
    joints = default_joints(list(trial.bones))
    kin = {}
    if joints:
        needed = {b for j in joints for b in (j.proximal, j.distal)}
        frames = anatomical_frames({b: volume_points(study.bone_volume(b)) for b in needed})
        for j in joints:
            js = joint_series(poses, j, frames)
            kin[j.name] = {"proximal": j.proximal, "distal": j.distal, "angles_deg": js["angles_deg"],
                           "names": list(j.angle_names),
                           "helical_angle_deg": js["helical_angle_deg"]}
    return {"study": study.name, "folder": str(study.folder), "trial": trial_name, "n_frames": n,
            "calibration": _calibration(study, trial), "bones": bones, "run": run,
            "flagged": sorted(flagged, key=lambda d: (d["frame"], d["bone"])), "kinematics": kin,
            "scores": {b: trial.scores(b) for b in trial.bones}}


def _figure(summary: dict):
    import matplotlib

    matplotlib.use("Agg", force=False)
    from matplotlib.figure import Figure

    kin = summary["kinematics"]
    rows = 1 + len(kin)
    fig = Figure(figsize=(7.5, 1.9 * rows), dpi=110, layout="constrained")
    axes = fig.subplots(rows, 1, sharex=True, squeeze=False)[:, 0]
    x = np.arange(summary["n_frames"])
    flagged = sorted({d["frame"] for d in summary["flagged"]})
    ax = axes[0]
    for b, s in summary["scores"].items():
        ax.plot(x, s, marker=".", lw=1, label=b)
    ax.set_ylabel("score")
    ax.set_title("similarity score per frame", fontsize=9)
    ax.legend(fontsize=7, ncol=4)
    for ax, (name, k) in zip(axes[1:], kin.items(), strict=True):
        a = np.asarray(k["angles_deg"], float)
        for c in range(3):
            ax.plot(x, a[:, c], marker=".", lw=1, label=k["names"][c])
        ax.set_ylabel("°")
        ax.set_title(f"{name} ({k['proximal']}–{k['distal']}): Grood–Suntay JCS angles", fontsize=9)
        ax.legend(fontsize=7, ncol=3)
    for ax in axes:
        for f in flagged:
            ax.axvspan(f - 0.5, f + 0.5, color=(0.86, 0.27, 0.24), alpha=0.18, lw=0)
        ax.grid(alpha=0.3)
        ax.tick_params(labelsize=7)
    axes[-1].set_xlabel("frame (0-based)")
    return fig


def _fmt(v, spec=".3f") -> str:
    return "–" if v is None or (isinstance(v, float) and not np.isfinite(v)) else format(v, spec)


def _lines(summary: dict) -> tuple[list[str], list[list[str]], list[str]]:
    """Calibration lines, the tracking table (header first) and flagged lines."""
    cal = summary["calibration"]
    cl = [f"calibration {cal['name']}"]
    q = cal.get("quality") or {}
    if q:
        cl.append(f"{q.get('method', '')}: reprojection RMS {_fmt(q.get('rms_px'))} px over "
                  f"{q.get('n_frames', '–')} frames, {q.get('n_observations', '–')} observations")
    for c in cal["cameras"]:
        sid = f", source–image distance {c['sid_mm']:.0f} mm" if c.get("sid_mm") else ""
        cl.append(f"{c['name']}: {c['image_px'][0]}×{c['image_px'][1]} px, focal {c['focal_px']:.1f} px{sid}")
    cl.extend(f"warning: {w}" for w in cal.get("warnings") or [])
    table = [["bone", "tracked", "flagged", "keyframes", "edited", "median score", "median σ mm",
              "median σ °"]]
    for b in summary["bones"]:
        table.append([b["bone"], str(b["tracked"]), str(b["flagged"]), str(b["keyframes"]), str(b["edited"]),
                      _fmt(b["median_score"]), _fmt(b["median_sigma_mm"]), _fmt(b["median_sigma_deg"])])
    fl = [f"frame {d['frame']} {d['bone']}: {'; '.join(d['reasons'])}" for d in summary["flagged"]]
    return cl, table, fl


def _joint_line(name: str, k: dict) -> str:
    """One joint's angle ranges over the tracked frames, e.g. ``ankle (tibia–talus): flexion …``."""
    a = np.asarray(k["angles_deg"], float).reshape(-1, len(k["names"]))
    parts = []
    for i, n in enumerate(k["names"]):
        v = a[:, i][np.isfinite(a[:, i])]
        parts.append(f"{n} {v.min():.1f} to {v.max():.1f}°" if len(v) else f"{n} –")
    return f"{name} ({k['proximal']}–{k['distal']}): " + ", ".join(parts)


def _html(summary: dict, png: bytes) -> str:
    e = html.escape
    cl, table, fl = _lines(summary)
    run = summary.get("run") or {}
    runline = (f"last run: {e(str(run.get('status', '–')))}, {run.get('results', '–')} results, "
               f"{_fmt(run.get('time_per_frame_s'), '.2f')} s per frame") if run else "no tracking run report"
    rows = "".join("<tr>" + "".join(f"<t{'h' if i == 0 else 'd'}>{e(c)}</t{'h' if i == 0 else 'd'}>"
                                    for c in r) + "</tr>" for i, r in enumerate(table))
    flagged = "".join(f"<li>{e(t)}</li>" for t in fl) or "<li>none</li>"
    joints = "".join(f"<li>{e(_joint_line(name, k))}</li>" for name, k in summary["kinematics"].items())
    joints = joints or "<li>no joint between two bones of this trial</li>"
    img = base64.b64encode(png).decode("ascii")
    return f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>Talus report: {e(summary['trial'])}</title>
<style>body{{font:13px sans-serif;max-width:60em;margin:1em auto}}table{{border-collapse:collapse}}
td,th{{border:1px solid #bbb;padding:2px 6px;text-align:right}}th{{background:#eee}}h1{{font-size:18px}}
h2{{font-size:14px;margin-bottom:2px}}</style></head><body>
<h1>Trial {e(summary['trial'])} — study {e(str(summary['study']))}</h1>
<p>{e(summary['folder'])}; {summary['n_frames']} frames (numbered from 0)</p>
<h2>Calibration</h2><ul>{''.join(f'<li>{e(t)}</li>' for t in cl)}</ul>
<h2>Tracking</h2><p>{runline}</p><table>{rows}</table>
<h2>Plots</h2><img alt="scores and joint angles" style="max-width:100%" src="data:image/png;base64,{img}">
<h2>Joint angles (Grood–Suntay)</h2><ul>{joints}</ul>
<h2>Flagged frames</h2><ul>{flagged}</ul>
</body></html>
"""


def write_report(study, trial_name: str, path: str | os.PathLike) -> Path:
    """Write the trial report to ``path`` (``.html`` or ``.pdf``) atomically; returns the path."""
    from ..io.atomic import atomic_path, atomic_write, output_file

    p = output_file(path, (".html", ".htm", ".pdf"), "an .html or .pdf file")
    suffix = p.suffix.lower()
    summary = trial_summary(study, trial_name)
    fig = _figure(summary)
    if suffix != ".pdf":
        buf = io.BytesIO()
        fig.savefig(buf, format="png")
        atomic_write(p, _html(summary, buf.getvalue()))
        return p
    from matplotlib.backends.backend_pdf import PdfPages
    from matplotlib.figure import Figure

    cl, table, fl = _lines(summary)
    page = Figure(figsize=(8.27, 11.69), dpi=100)
    page.text(0.06, 0.97, f"Trial {summary['trial']} — study {summary['study']}", fontsize=13, va="top",
              weight="bold")
    text = (["Calibration"] + ["  " + t for t in cl] + ["", "Tracking"]
            + ["  " + "  ".join(f"{c:>10}" for c in r) for r in table]
            + ["", "Flagged frames"] + ["  " + t for t in (fl[:12] or ["none"])]
            + ([f"  … and {len(fl) - 12} more"] if len(fl) > 12 else []))
    page.text(0.06, 0.94, "\n".join(text), fontsize=7, va="top", family="monospace")
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    import matplotlib.image as mpimg

    buf.seek(0)
    ax = page.add_axes((0.05, 0.03, 0.9, 0.5))
    ax.imshow(mpimg.imread(buf, format="png"))
    ax.axis("off")
    with atomic_path(p) as tmp, PdfPages(tmp) as pdf:
        pdf.savefig(page)
    return p
