"""A calibration session, end to end: raw frames → correction pipelines and a calibrated rig.

:func:`calibrate_session` runs, per camera and then for the rig, the steps a lab runs at the
start of a collection day (thesis Ch. 3 and 5):

1. **flatfield** — dark frames averaged into a dark frame, empty-field frames of the session's
   kV into the fluence surface (:func:`core.imaging.flatfield.build_flatfield`);
2. **distortion** — every grid frame detected and indexed, frames of one placement merged, the
   ideal grid refined, the model chosen by cross-validation (``model="auto"``) or as given, and
   its residuals (:mod:`core.calibration._session_grid`); with ``"glare"`` frames (a lead disc on
   the intensifier) the veiling glare is measured too (:func:`core.imaging.glare.estimate_glare`)
   and undone in the pipeline (``dark → flatfield → glare → undistort``);
3. **beads** — spiral and cube frames corrected by ``dark → flatfield → undistort``
   (:class:`core.imaging.pipeline.Pipeline`), beads detected, sized
   (:func:`core.calibration.detection.detect_object_beads`) and labelled in both views with the
   epipolar geometry estimated from the sequence (:func:`core.calibration.matching.label_sequence`);
4. **DLT start and bundle adjustment** — the rigid rig from all labelled frames
   (:func:`core.calibration.bundle.bundle_adjust`, whose initial guess is per-frame DLTs), the lab
   frame from the static cube frame (a cube frame that cannot be labelled is an error; a session
   without one, or ``lab_frame="object"``, puts the lab in the first spiral frame and says so in
   ``report["warnings"]``), an SID prior when the session gives one; parameter standard
   deviations;
5. **report** — per step figures of merit (:attr:`SessionCalibration.report`).

A *session* is anything with the reading interface of
:class:`core.io.calibration_session.CalibrationSession`: ``cameras``, ``manifest``,
``frames(camera, group)`` (the frame references of ``"dark"``, ``"flat:<kV>"``, ``"grid"``, ``"glare"``,
``"cube"``, ``"spiral"``) and ``read(ref)`` (float32 raw counts).

Every step raises :class:`SessionError` on bad input, naming the step, the file and frame, what
was expected and what can be done; nothing is written anywhere (saving into a study is
:mod:`core.study.calibrations`). ``progress(step, done, total)`` is called as work advances and
``cancel()`` is polled between frames (:class:`CalibrationCancelled` is raised when it returns
True).

The module holds the steps and their results; reading the session (errors, the checked frame
reader, the manifest) is :mod:`core.calibration._session_input`, the per-camera work on frames
(flatfield, grid, lattice, bead detection) :mod:`core.calibration._session_frames`, and the beads
step's result with its edits :mod:`core.calibration._session_beads`; their public names are
importable from here.

Pixels are ``(u, v) = (column, row)``, origin at the centre of the top-left pixel; mm, radians.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np

from ..geometry.camera import Rig
from ..imaging.flatfield import Flatfield
from ..imaging.pipeline import Pipeline
from . import _session_grid as grids
from ._session_beads import BeadsStep, exclude_frames, relabel
from ._session_frames import (
    CameraCorrection,  # noqa: F401  (re-exported: SessionCalibration.cameras)
    _beads,
    _correction,
    _distortion,
    _flatfield,
    _glare,
    _lattice,
)
from ._session_input import (
    DEFAULTS,
    CalibrationCancelled,
    SessionError,
    _flat_groups,
    _manifest_T,
    _pixel_size,
    _Reader,
    _target,
)
from .bundle import BundleResult, bundle_adjust
from .dlt import calibrate_dlt
from .matching import label_sequence
from .objects import CalibrationTarget

__all__ = ["BeadsStep", "CalibrationCancelled", "DistortionStep", "SessionCalibration", "SessionError",
           "SessionSetup", "beads_step", "calibrate_session", "distortion_step", "exclude_frames",
           "flatfield_step", "prepare", "refit_distortion", "relabel", "solve_step"]

MIN_LABELLED_FRAMES = 8
#: What defines the lab frame (:func:`solve_step`): the static object's frame, or the moving object's first.
LAB_FRAMES = ("static", "object")


@dataclass(frozen=True, eq=False)
class SessionCalibration:
    """Result of :func:`calibrate_session`.

    Attributes
    ----------
    rig : Rig
        The calibrated cameras in the lab frame (the static object's frame), pixels of the
        *corrected* images.
    cameras : list of CameraCorrection
        Per camera: flatfield, distortion fit and the :class:`~core.imaging.pipeline.Pipeline`
        that turns raw frames into corrected fluence (``pipelines`` lists them alone).
    bundle : BundleResult
        The bundle adjustment (parameters, standard deviations, residuals per observation).
    frames : list of dict
        Per object frame: ``group``, ``index``, ``labelled`` (beads per view), ``ok``,
        ``reason`` and, once adjusted, ``rms_px``.
    observations : list of ObjectFrame
        The labelled frames given to the bundle adjustment, in ``frames`` order of the ok ones.
    target, static_target : CalibrationTarget
    report : dict
        JSON-ready figures of merit of every step (see :mod:`core.calibration.report`).
    """

    rig: Rig
    cameras: list
    bundle: BundleResult
    frames: list
    observations: list
    target: CalibrationTarget
    static_target: CalibrationTarget | None
    report: dict = field(default_factory=dict)

    @property
    def pipelines(self) -> list[Pipeline]:
        return [c.pipeline for c in self.cameras]

# ---------------------------------------------------------------------------- steps, one by one
@dataclass(eq=False)
class SessionSetup:
    """What every step reads: the session, its manifest, cameras, grid and objects (:func:`prepare`)."""

    session: object
    manifest: dict
    cameras: list
    pitch_mm: float
    feature_mm: float
    target: CalibrationTarget
    static: CalibrationTarget
    px_nominal: float | None
    reader: _Reader
    times: dict = field(default_factory=dict)


@dataclass(frozen=True, eq=False)
class DistortionStep:
    """Per camera: the correction, the grid placements found (a model can be refitted from them
    without reading a frame: :func:`refit_distortion`) and the bead-lattice check."""

    cameras: list
    placements: list
    lattice: dict


def prepare(session, *, object=None, static_object=None, cancel=None) -> SessionSetup:
    """Check the session's cameras and read its grid and objects (step 0 of :func:`calibrate_session`)."""
    man = dict(getattr(session, "manifest", {}) or {})
    cams = [str(c) for c in getattr(session, "cameras", ())]
    if len(cams) != 2:
        raise SessionError("session", "cameras", f"expected the 2 cameras of a biplane rig, got {cams}",
                           "check the session manifest's camera list")
    grid_man = man.get("grid") or {}
    pitch = float(grid_man.get("pitch_mm", DEFAULTS["pitch_mm"]))
    feature_mm = float(grid_man.get("hole_diameter_mm", grid_man.get("feature_diameter_mm",
                                                                      DEFAULTS["hole_diameter_mm"])))
    objs = man.get("objects") or {}
    target = _target(object or objs.get("spiral") or man.get("object") or DEFAULTS["object"], "object")
    static = _target(static_object or objs.get("cube") or man.get("static_object")
                     or DEFAULTS["static_object"], "static_object")
    return SessionSetup(session, man, cams, pitch, feature_mm, target, static, _pixel_size(man),
                        _Reader(session, cancel))


def _say(progress):
    return progress or (lambda step, done, total: None)


def flatfield_step(setup: SessionSetup, *, kv=None, progress=None) -> list[tuple[Flatfield, float | None]]:
    """Step 1: ``(flatfield, kV used)`` per camera."""
    out = []
    for cam in setup.cameras:
        t = time.perf_counter()
        out.append(_flatfield(setup.reader, cam, _flat_groups(setup.session, cam), kv, _say(progress)))
        setup.times[f"flatfield {cam}"] = time.perf_counter() - t
    return out



def distortion_step(setup: SessionSetup, flatfields, *, model: str = "auto", progress=None) -> DistortionStep:
    """Step 2: the distortion model of every camera and its correction pipeline."""
    rd, corr, placements, lattice = setup.reader, [], [], {}
    for cam, (ff, used_kv) in zip(setup.cameras, flatfields, strict=True):
        t = time.perf_counter()
        px = setup.px_nominal or 300.0 / max(rd.shape[cam][0])  # a 300 mm field when not given
        fit, pl = _distortion(rd, cam, ff, model=model, pitch=setup.pitch_mm, feature_mm=setup.feature_mm,
                              px_mm=px, progress=_say(progress))
        setup.times[f"distortion {cam}"] = time.perf_counter() - t
        groups = _flat_groups(setup.session, cam)
        flat_group = next((g for k, g in groups if k == used_kv), groups[0][1])
        t = time.perf_counter()
        glare = _glare(rd, cam, ff, flat_group, fit, _say(progress))
        if glare is not None:
            setup.times[f"glare {cam}"] = time.perf_counter() - t
        corr.append(_correction(cam, ff, used_kv, fit, glare))
        placements.append(pl)
        lattice[cam] = _lattice(rd, cam, corr[-1], setup.manifest)
    return DistortionStep(corr, placements, lattice)


def refit_distortion(setup: SessionSetup, dist: DistortionStep, camera: int, model: str) -> DistortionStep:
    """``dist`` with camera ``camera``'s model refitted as ``model`` (a label, or ``"auto"``) from
    the grid points already found (the model table of an ``"auto"`` fit is kept)."""
    c = dist.cameras[camera]
    shape = c.flatfield.shape
    centre = ((shape[1] - 1) / 2, (shape[0] - 1) / 2)
    try:
        fit = grids.fit_view(dist.placements[camera], model=model, pitch_mm=setup.pitch_mm, center=centre,
                             n_frames=c.grid.n_frames)
    except ValueError as exc:
        raise SessionError("distortion", f"camera {c.name}", str(exc), "choose another model") from None
    if not fit.table and c.grid.table:
        fit = replace(fit, table=c.grid.table)
    cams = list(dist.cameras)
    cams[camera] = _correction(c.name, c.flatfield, c.kv, fit, c.glare)
    lattice = dict(dist.lattice)
    lattice[c.name] = _lattice(setup.reader, c.name, cams[camera], setup.manifest)
    return DistortionStep(cams, dist.placements, lattice)


def beads_step(setup: SessionSetup, dist: DistortionStep, *, progress=None) -> BeadsStep:
    """Step 3: beads of the object (and static object) frames detected and labelled in both views."""
    say, rd, cams, corr = _say(progress), setup.reader, setup.cameras, dist.cameras
    t = time.perf_counter()
    refs, dets = _beads(rd, cams, corr, "spiral", setup.target, say)
    try:
        frames, _, F = label_sequence(setup.target, dets)
    except ValueError as exc:  # not one frame labelled well enough to estimate the epipolar geometry
        found = ", ".join(f"{len(a)}/{len(b)}" for a, b in dets[:10]) + (" …" if len(dets) > 10 else "")
        crowded = np.median([max(len(a), len(b)) for a, b in dets]) >= 2 * len(setup.target)
        raise SessionError("beads", f"{setup.target.name} frames ({refs[0][0]} to {refs[0][-1]}, "
                           f"{len(dets)} frames)", f"no frame could be labelled in both views ({exc}; "
                           f"detections per frame, view 1/view 2: {found})",
                           "record more frames with the whole object inside both views, or check the "
                           "object definition (--object)"
                           + ("; many more detections than beads: check the dark and empty-field "
                              "frames (more of them give a smoother flatfield)" if crowded else "")) from None
    setup.times["beads spiral"] = time.perf_counter() - t
    srefs, sdets, sframes = [], [], []
    if rd.refs(cams[0], "cube", required=False):
        srefs, sdets = _beads(rd, cams, corr, "cube", setup.static, say)
        sframes, _, _ = label_sequence(setup.static, sdets, F=F)
    return BeadsStep(frames, dets, refs, sframes, sdets, srefs, F)


def _lab_frame(lab_frame: str, target, static, static_obs, static_rows) -> tuple[list, str, list[str]]:
    """The static observations that define the lab (none: the object's first labelled frame),
    the report's note and its warnings; :class:`SessionError` when a recorded static frame was
    not labelled and ``lab_frame`` is ``"static"``."""
    if lab_frame not in LAB_FRAMES:
        raise ValueError(f"lab_frame: expected one of {LAB_FRAMES}, got {lab_frame!r}")
    if lab_frame == "static" and static_obs:
        return static_obs, f"lab frame: the static {static.name} frame", []
    fallback = f"lab frame: the {target.name} in its first labelled frame"
    missed = [r for r in static_rows if not r["ok"]]
    if lab_frame == "static" and missed:
        r = missed[0]
        raise SessionError("beads", f"{r['files'][0]} ({static.name} frame {r['index']})",
                           f"the static {static.name} frame was recorded but could not be labelled "
                           f"({r['reason']}); it defines the lab frame",
                           f"record the {static.name} again with all its beads inside both views, or "
                           f"calibrate with the lab frame in the {target.name}'s first labelled frame "
                           "(lab_frame='object'; talus calibrate --lab-frame object): the cameras are "
                           f"then not in the {static.name}'s frame")
    if lab_frame == "object":
        why = f"asked for; the static {static.name} frame is not used" if static_rows else "asked for"
        return [], f"{fallback} ({why})", [
            f"the lab frame is the {target.name}'s first labelled frame, not the static "
            f"{static.name}'s: the cameras and every pose tracked with them are in that frame"]
    return [], f"{fallback} (the session has no static {static.name} frame)", [
        f"the session has no static {static.name} frame: the lab frame is the {target.name}'s first "
        "labelled frame, an arbitrary pose of a hand-held object (record a static object frame to "
        "fix the lab frame)"]


def solve_step(setup: SessionSetup, dist: DistortionStep, beads: BeadsStep, *, sid_prior=None,
               pixel_sigma: float = 0.1, lab_frame: str = "static", progress=None) -> SessionCalibration:
    """Steps 4-5: DLT start, bundle adjustment and the report.

    ``lab_frame``: ``"static"`` (default) puts the lab in the static object's frame; a static frame
    that was recorded but not labelled is then a :class:`SessionError`, and a session without one
    falls back to the moving object's first labelled frame with a warning in the report
    (``report["warnings"]``). ``"object"`` asks for the moving object's first labelled frame.
    """
    say, rd, cams, man = _say(progress), setup.reader, setup.cameras, setup.manifest
    target, static, corr = setup.target, setup.static, dist.cameras
    rows, static_rows = beads.rows()
    obs, static_obs = beads.observations(target, static)
    static_obs, lab_note, warnings = _lab_frame(lab_frame, target, static, static_obs, static_rows)
    n_ok = len(obs)
    if n_ok < MIN_LABELLED_FRAMES:
        bad = [r for r in rows if not r["ok"]][:3]
        ex = "; ".join(f"{r['files'][0]} (frame {r['index']}): {r['reason']}" for r in bad)
        raise SessionError("beads", f"{target.name} frames", f"only {n_ok} of {len(rows)} frames could be "
                           f"labelled in both views, the bundle adjustment needs {MIN_LABELLED_FRAMES}"
                           + (f" (e.g. {ex})" if ex else ""),
                           "record more frames with the whole object inside both views, or check "
                           "the object definition (--object)")
    if setup.reader.cancel is not None and setup.reader.cancel():
        raise CalibrationCancelled("cancelled before the bundle adjustment")
    # corrected pixels have the raw pixels' size at the centre: the detector's pixel pitch when the
    # session gives it (the grid lies a few mm above the detector, so its own scale reads ~0.3 % small)
    px_nominal = setup.px_nominal
    px_mm = [px_nominal or c.grid.mm_per_px for c in corr]
    t = time.perf_counter()
    sizes = [tuple(int(a) for a in rd.shape[c][0][::-1]) for c in cams]
    all_obs = list(obs) + list(static_obs)
    if static_obs:
        reference, T_ref = len(obs), _manifest_T(man)
    else:
        reference, T_ref = 0, None
    if sid_prior is None and man.get("sid_mm") is not None:
        sids = man["sid_mm"] if np.ndim(man["sid_mm"]) else [man["sid_mm"]] * 2
        sid_prior = [(float(s), float(man.get("sid_tolerance_mm", 20.0))) for s in sids]
    dlt = []
    first = static_obs[0] if static_obs else obs[0]
    for v, c in enumerate(cams):
        d = calibrate_dlt(first.points, first.uv[v], width=sizes[v][0], height=sizes[v][1],
                          pixel_size=px_mm[v], max_skew_px=1e9)
        dlt.append({"camera": c, "ok": bool(d.ok), "reason": d.reason,
                    "fx_px": d.camera.fx if d.ok else None,
                    "source_mm": d.camera.source.tolist() if d.ok else None})
    say("bundle adjustment", 0, 1)
    ba = bundle_adjust(all_obs, sizes, reference=reference, T_lab_from_reference=T_ref, pixel_size=px_mm,
                       sid_prior=sid_prior, pixel_sigma=pixel_sigma, max_evaluations=400)
    times = setup.times
    times["bundle adjustment"] = time.perf_counter() - t
    say("bundle adjustment", 1, 1)
    if not ba.ok:
        raise SessionError("bundle", f"{len(all_obs)} labelled frames ({target.name}"
                           + (f" + {static.name}" if static_obs else "") + ")",
                           f"the bundle adjustment did not converge: {ba.reason}",
                           "check the labelled frames in the report, remove frames with wrong labels, "
                           "or give the SID (sid_mm in the session manifest) as a prior")
    named = []
    for c, cam in zip(ba.rig, cams, strict=True):
        named.append(type(c)(c.K, c.R, c.t, c.width, c.height, c.pixel_size, cam))
    rig = Rig(tuple(named))
    if not static_obs:
        for r in static_rows:  # not in the solve (the lab frame is the object's)
            r["ok"], r["reason"] = False, r["reason"] or "not used: the lab frame is the object's"
    ok_rows = [r for r in rows if r["ok"]] + [r for r in static_rows if r["ok"]]
    err = ba.errors_px
    for f, r in enumerate(ok_rows):
        sel = ba.frame_index == f
        r["rms_px"] = float(np.sqrt(np.mean(err[sel] ** 2))) if sel.any() else None
        r["outliers"] = int(ba.outliers[sel].sum())
    times["total"] = sum(v for k, v in times.items() if k != "total")
    result = SessionCalibration(rig, corr, ba, rows + static_rows, all_obs, target,
                                static if static_obs else None)
    from .report import session_report

    notes = [lab_note] + ([] if px_nominal else ["no detector pixel size in the session manifest: "
                                                 "a 300 mm field was assumed to size the grid holes"])
    result.report.update(session_report(result, notes=notes, dlt=dlt, seconds=dict(times), manifest=man,
                                        lattice=dist.lattice))
    result.report["lab_frame"] = {"defined_by": "static" if static_obs else "object",
                                  "object": static.name if static_obs else target.name,
                                  "frame": (next(r["files"] for r in static_rows if r["ok"]) if static_obs
                                            else next(r["files"] for r in rows if r["ok"]))}
    result.report["warnings"] = warnings
    return result


# ---------------------------------------------------------------------------- main
def calibrate_session(session, *, object=None, static_object=None, model: str = "auto", kv=None,
                      sid_prior=None, pixel_sigma: float = 0.1, lab_frame: str = "static",
                      progress: Callable[[str, int, int], None] | None = None,
                      cancel: Callable[[], bool] | None = None) -> SessionCalibration:
    """Correction pipelines and the calibrated rig from a calibration session (module docs).

    The steps one by one (the calibration wizard runs them separately, keeping each result):
    :func:`prepare` → :func:`flatfield_step` → :func:`distortion_step` → :func:`beads_step`
    (edited by :func:`exclude_frames` / :func:`relabel`) → :func:`solve_step`.

    Parameters
    ----------
    session : CalibrationSession
        The session (see the module docs for the interface).
    object : str, CalibrationTarget or path, optional
        The object moved through the volume (default: the manifest's ``object``, else spiral33).
    static_object : str, CalibrationTarget or path, optional
        The static object that defines the lab frame (default: the manifest's, else cube15).
    model : str
        Distortion model: ``"auto"`` (cross-validated choice), ``"poly(N,M)"``, ``"tps"``,
        ``"lwm"`` (any :class:`~core.imaging.distortion_models.ModelSpec` label).
    kv : float, optional
        Which empty-field set to use (nearest kV; default the first).
    sid_prior : sequence of (SID_mm, tolerance_mm), optional
        Per camera; default from the manifest's ``sid_mm`` (± ``sid_tolerance_mm``, 20 mm).
    pixel_sigma : float
        Expected bead localisation noise (px), the weight of the reprojection residuals.
    lab_frame : {"static", "object"}
        What defines the lab frame (:func:`solve_step`): the static object (default; a recorded
        static frame that cannot be labelled is an error) or the moving object's first labelled
        frame. Whenever the lab is not the static object's frame, ``report["warnings"]`` says so.
    progress : callable(step, done, total), optional
    cancel : callable() -> bool, optional

    Raises
    ------
    SessionError
        A step could not run (missing view, frames of different sizes, a grid frame without a
        grid, too few labelled frames, a static object frame that cannot be labelled, a bundle
        adjustment that does not converge).
    CalibrationCancelled
        ``cancel()`` returned True.
    """
    if lab_frame not in LAB_FRAMES:
        raise ValueError(f"lab_frame: expected one of {LAB_FRAMES}, got {lab_frame!r}")
    setup = prepare(session, object=object, static_object=static_object, cancel=cancel)
    ffs = flatfield_step(setup, kv=kv, progress=progress)
    dist = distortion_step(setup, ffs, model=model, progress=progress)
    beads = beads_step(setup, dist, progress=progress)
    return solve_step(setup, dist, beads, sid_prior=sid_prior, pixel_sigma=pixel_sigma, lab_frame=lab_frame,
                      progress=progress)
