"""The calibration wizard's work, run in its worker pool (never on the GUI thread): one function
per step, each the core step of ``talus calibrate`` (:mod:`core.calibration.session`) plus what its
page draws (corrected frames, figures). Steps honour ``cancel()`` between frames and report
``progress(done, total)``."""

from __future__ import annotations

from pathlib import Path

__all__ = ["flatfield_for", "job_beads", "job_distortion", "job_frame", "job_inspect", "job_refit",
           "job_save", "job_solve", "short_name"]


def _with(setup, cancel):
    setup.reader.cancel = cancel
    return setup


def job_inspect(folder: str) -> str:
    """What the session folder holds (read and checked by :func:`core.io.calibration_session.read_session`):
    cameras, frame size and bit depth, frames per group, the objects; a ``ValueError`` names what is
    wrong and where."""
    from core.io.calibration_session import read_session

    ses = read_session(folder)
    m = ses.manifest
    groups = ", ".join(f"{len(ses.frames(ses.cameras[0], g))} {g.replace('flat:', 'empty-field at ')}"
                       + (" kV" if g.startswith("flat:") else "") for g in ses.groups)
    objs = ", ".join(f"{k}: {v}" for k, v in ses.objects.items()) or "none named (give one when solving)"
    grid = m.get("grid") or {}
    lines = [f"{ses.root}",
             f"Cameras {', '.join(ses.cameras)}: {ses.frame_size[1]}x{ses.frame_size[0]} pixels, "
             f"{ses.bit_depth}-bit raw counts.",
             f"Frames per camera: {groups}.",
             f"Objects: {objs}."]
    if grid:
        lines.append(f"Distortion grid: {grid.get('kind', '?')} grid, pitch {grid.get('pitch_mm', '?')} mm.")
    if m.get("notes"):
        lines.append(f"Notes: {m['notes']}")
    return "\n".join(lines)


def job_flatfield(folder: str, *, cancel=None, progress=None):
    from core.calibration import session as cs
    from core.io.calibration_session import read_session

    from .figures import rolloff_figure

    setup = cs.prepare(read_session(folder), cancel=cancel)
    say = None if progress is None else (lambda s, d, t: progress(d, t))
    ffs = cs.flatfield_step(setup, progress=say)
    corrected = []
    for cam, (ff, kv) in zip(setup.cameras, ffs, strict=True):
        groups = cs._flat_groups(setup.session, cam)
        pick = groups[0] if kv is None else min(groups, key=lambda g: abs((g[0] or 0) - kv))
        ref = setup.reader.refs(cam, pick[1])[0]
        corrected.append(ff.normalise(setup.reader.read(cam, ref, 0, "flatfield")))
    return {"setup": setup, "flatfields": ffs, "corrected": corrected,
            "rolloff": rolloff_figure([f for f, _ in ffs], setup.cameras)}


def _grid_views(setup, dist) -> list:
    out = []
    for cam, c in zip(setup.cameras, dist.cameras, strict=True):
        ref = setup.reader.refs(cam, "grid")[0]
        img = c.flatfield.normalise(setup.reader.read(cam, ref, 0, "distortion"))
        g = c.grid
        sel = g.placement == 0
        resid = g.model.inverse(g.distorted_uv[sel]) - g.ideal_uv[sel]
        out.append({"image": img, "uv": g.distorted_uv[sel], "resid": resid, "ref": short_name(ref, setup)})
    return out


def short_name(ref, setup) -> str:
    """A frame's file relative to the session folder (the full path stays in the report)."""
    try:
        return str(Path(str(ref)).relative_to(setup.session.root))
    except (ValueError, AttributeError):
        return str(ref)


def job_distortion(setup, flatfields, model: str = "auto", *, cancel=None, progress=None):
    from core.calibration import session as cs

    say = None if progress is None else (lambda s, d, t: progress(d, t))
    dist = cs.distortion_step(_with(setup, cancel), flatfields, model=model, progress=say)
    return {"dist": dist, "views": _grid_views(setup, dist)}


def job_refit(setup, dist, camera: int, model: str, *, cancel=None):
    from core.calibration import session as cs

    new = cs.refit_distortion(_with(setup, cancel), dist, camera, model)
    return {"dist": new, "views": _grid_views(setup, new)}


def job_beads(setup, dist, *, cancel=None, progress=None):
    from core.calibration import session as cs

    say = None if progress is None else (lambda s, d, t: progress(d, t))
    return cs.beads_step(_with(setup, cancel), dist, progress=say)


def job_frame(setup, dist, beads, k: int):
    """The corrected images of object frame ``k`` (both views)."""
    return [c.pipeline(setup.reader.read(cam, beads.refs[v][k], k, "beads"))
            for v, (cam, c) in enumerate(zip(setup.cameras, dist.cameras, strict=True))]


def job_solve(setup, dist, beads, lab_frame: str = "static", *, cancel=None, progress=None):
    from core.calibration import session as cs

    from .figures import reprojection_figure

    say = None if progress is None else (lambda s, d, t: progress(d, t))
    cal = cs.solve_step(_with(setup, cancel), dist, beads, lab_frame=lab_frame, progress=say)
    import pyvista  # noqa: F401  (loaded here, off the GUI thread, for the page's 3-D scene)

    return {"cal": cal, "reprojection": reprojection_figure(cal), "lab_frame": lab_frame}


def job_save(study_folder: str, cal, series: str, trials, session_folder: str):
    from core.study import Study
    from core.study.calibrations import save_session_calibration

    with Study.open(study_folder, mode="w") as st:
        return save_session_calibration(st, cal, series=series, trials=trials, session_path=session_folder)


def flatfield_for(folder: str, *, cancel=None, progress=None):
    out = job_flatfield(folder, cancel=cancel, progress=progress)
    out["folder"] = folder
    return out
