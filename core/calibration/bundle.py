"""Rigid-rig bundle adjustment over many frames of a calibration object (thesis §5.4.3).

Model
-----
The rig frame is camera 1's frame. Unknowns (``scipy.optimize.least_squares``, trust-region
reflective with an analytic, sparse Jacobian and a robust loss):

* per camera: ``f`` (or ``fx, fy`` with ``focal="separate"``) and the principal point
  ``(cu, cv)`` in pixels (held at a given value with ``fixed_principal_point``);
* the rigid rig: ``T_cam_c_from_cam_1`` for cameras 2.. (rotation vector + translation, mm);
* per frame: the object pose ``T_cam_1_from_object`` (the object moved through the volume).

Rotations are parameterised as ``exp(ω) R₀`` about the initial guess ``R₀``. Residuals are
reprojection errors divided by ``pixel_sigma`` (the expected localisation noise, px), plus optional
priors: a measured source-to-image distance ``(f · pixel_size - SID) / tolerance`` per camera.
The lab frame is the object's frame in a chosen static frame ``reference`` (optionally placed
with a known ``T_lab_from_reference``), so the cameras come out as
``T_cam_from_lab = T_cam_from_cam1 · T_cam1_from_object[reference] · T_lab_from_reference⁻¹``.
A static frame of another object (e.g. the cube on the walkway) may join with its own points.
The DLT is only the initial guess (median intrinsics over frames, PnP poses, averaged rig).

Parameter standard deviations come from the Jacobian at the solution: ``cov = s² (JᵀJ)⁻¹`` with
``s²`` the a-posteriori variance of unit weight; derived quantities (source positions, SID) are
propagated through their own Jacobian.

Pixels are ``(u, v) = (column, row)``, origin at the centre of the top-left pixel; mm, radians.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from .._validate import as_float_array, positive
from ..geometry.camera import Camera, Rig, make_K
from . import _bundle_init as init
from . import _so3
from ._bundle_model import Problem, covariance

__all__ = ["BundleResult", "ObjectFrame", "bundle_adjust"]


@dataclass(frozen=True, eq=False)
class ObjectFrame:
    """One frame of observations: object points ``(n, 3)`` mm in the object frame and their
    image positions ``uv (V, n, 2)`` px in every view (NaN = not seen)."""

    points: np.ndarray
    uv: np.ndarray

    def __post_init__(self) -> None:
        X = as_float_array(self.points, "points", shape=(None, 3))
        x = as_float_array(self.uv, "uv", ndim=3, finite=False)
        if x.shape[1:] != (len(X), 2):
            raise ValueError(f"uv: expected shape (V, {len(X)}, 2) for {len(X)} points, got {x.shape}")
        if np.any(np.isinf(x)) or np.any(np.isnan(x[..., 0]) != np.isnan(x[..., 1])):
            raise ValueError("uv: expected finite (u, v) pairs or NaN pairs for unseen points")
        object.__setattr__(self, "points", X)
        object.__setattr__(self, "uv", x)


@dataclass(frozen=True, eq=False)
class BundleResult:
    """Result of :func:`bundle_adjust`.

    Attributes
    ----------
    ok : bool
        False when no trustworthy rig was found (``rig`` is None, ``reason`` says why).
    reason : str
    rig : Rig or None
        Calibrated cameras in the lab frame.
    relative_poses : (V, 4, 4)
        ``T_cam_c_from_cam_1`` (the rigid rig).
    object_poses : (F, 4, 4)
        ``T_lab_from_object`` of every frame.
    parameter_names : tuple of str
    parameters, std : (P,) arrays
        Optimised parameters and their standard deviations (same units: px, rad, mm).
    camera_std : list of dict
        Per camera: standard deviation of ``f`` (px), ``cu``, ``cv`` (px), ``source`` (3, mm,
        lab) and ``sid`` (mm, when the pixel size is known).
    frame_index, view, point_index : (M,) int arrays
        Which frame, view and point each observation is.
    residuals : (M, 2)
        Reprojected minus observed position, px.
    outliers : (M,) bool
        Observations farther than 5 robust standard deviations (Rayleigh: median / 1.1774) from
        their reprojection (mislabelled or badly localised beads).
    sigma0 : float
        A-posteriori standard deviation of unit weight (≈1 when ``pixel_sigma`` is right).
    n_evaluations : int
    message : str
        The optimizer's message.
    """

    ok: bool
    reason: str
    rig: Rig | None
    relative_poses: np.ndarray
    object_poses: np.ndarray
    parameter_names: tuple[str, ...]
    parameters: np.ndarray
    std: np.ndarray
    camera_std: list
    frame_index: np.ndarray
    view: np.ndarray
    point_index: np.ndarray
    residuals: np.ndarray
    outliers: np.ndarray
    sigma0: float
    n_evaluations: int
    message: str

    @property
    def errors_px(self) -> np.ndarray:
        """``(M,)`` reprojection distance of every observation, px."""
        return np.linalg.norm(self.residuals, axis=1)

    @property
    def rms_px(self) -> float:
        """Root-mean-square reprojection distance of the inliers, px."""
        e = self.errors_px[~self.outliers]
        return float(np.sqrt(np.mean(e**2))) if e.size else float("nan")

    @property
    def rms_all_px(self) -> float:
        """Root-mean-square reprojection distance of all observations, px."""
        e = self.errors_px
        return float(np.sqrt(np.mean(e**2))) if e.size else float("nan")

    def parameter(self, name: str) -> tuple[float, float]:
        """``(value, std)`` of a named parameter (see ``parameter_names``)."""
        if name not in self.parameter_names:
            raise ValueError(f"name: expected one of {self.parameter_names}, got {name!r}")
        i = self.parameter_names.index(name)
        return float(self.parameters[i]), float(self.std[i])


# ---------------------------------------------------------------------------- options
def _per_camera(value, V: int, name: str, check):
    if value is None:
        return [None] * V
    if not isinstance(value, Sequence | np.ndarray) or len(value) != V:
        raise ValueError(f"{name}: expected one entry (or None) per camera ({V}), got {value!r}")
    return [None if v is None else check(v) for v in value]


def _pp(v):
    a = as_float_array(v, "fixed_principal_point", shape=(2,))
    return a


def _sid(v):
    if np.ndim(v) != 1 or len(v) != 2:
        raise ValueError(f"sid_prior: expected (sid_mm, tolerance_mm) per camera, got {v!r}")
    return positive(v[0], "sid_prior"), positive(v[1], "sid_prior tolerance")


def _failure(reason: str, V: int, F: int) -> BundleResult:
    e = np.zeros(0, np.int64)
    return BundleResult(False, reason, None, np.full((V, 4, 4), np.nan), np.full((F, 4, 4), np.nan),
                        (), np.zeros(0), np.zeros(0), [], e, e, e, np.zeros((0, 2)), np.zeros(0, bool),
                        float("nan"), 0, "")


# ---------------------------------------------------------------------------- main
def bundle_adjust(
    frames: Sequence[ObjectFrame],
    image_sizes: Sequence[tuple[int, int]],
    *,
    initial: Rig | None = None,
    reference: int = 0,
    T_lab_from_reference=None,
    focal: str = "single",
    fixed_principal_point=None,
    pixel_size=None,
    sid_prior=None,
    pixel_sigma: float = 0.1,
    loss: str = "soft_l1",
    loss_scale: float = 4.0,
    max_rms_px: float = 2.0,
    max_outliers: float = 0.2,
    max_evaluations: int = 200,
) -> BundleResult:
    """Calibrate a rigid rig of ``V`` cameras from many frames of a calibration object.

    Parameters
    ----------
    frames : sequence of ObjectFrame
        Labelled observations, one entry per object pose (frames may hold different objects).
    image_sizes : sequence of (width, height)
        Per camera, pixels.
    initial : Rig, optional
        A rough rig (intrinsics and relative poses are used; its lab frame is ignored). Default:
        from per-frame DLTs.
    reference : int
        Index of the static frame whose object frame defines the lab.
    T_lab_from_reference : (4, 4) array, optional
        Pose of that object in the lab (default identity: the lab *is* the object frame).
    focal : {"single", "separate"}
        One focal length per camera (square pixels) or ``fx, fy``.
    fixed_principal_point : sequence, optional
        Per camera ``(cu, cv)`` px to hold fixed, or None to estimate.
    pixel_size : float or sequence, optional
        Detector pixel pitch (mm) per camera (needed by ``sid_prior``, gives each camera's SID).
    sid_prior : sequence, optional
        Per camera ``(SID_mm, tolerance_mm)`` (a measured source-to-image distance) or None.
    pixel_sigma : float
        Expected localisation noise (px): the weight of the reprojection residuals.
    loss : {"linear", "huber", "soft_l1", "cauchy"}
        Robust loss of :func:`scipy.optimize.least_squares`; ``loss_scale`` is its soft
        threshold in units of ``pixel_sigma``.
    max_rms_px : float
        A solution whose reprojection RMS (inliers) exceeds this is reported as failed.
    max_outliers : float
        Largest accepted fraction of outlying observations (see ``BundleResult.outliers``).
    max_evaluations : int
        Function evaluations allowed to the optimizer.

    Returns
    -------
    BundleResult
        ``ok=False`` with a ``reason`` (no frames, a camera never observed, no initial guess,
        no convergence, residuals too large); otherwise the calibrated rig in the lab frame.
    """
    frames = list(frames)
    if not frames or not all(isinstance(f, ObjectFrame) for f in frames):
        raise ValueError("frames: expected a non-empty sequence of ObjectFrame")
    sizes = [tuple(int(a) for a in s) for s in image_sizes]
    V, F = len(sizes), len(frames)
    if V < 1 or any(len(s) != 2 or min(s) < 1 for s in sizes):
        raise ValueError(f"image_sizes: expected (width, height) per camera, got {image_sizes!r}")
    if any(fr.uv.shape[0] != V for fr in frames):
        raise ValueError(f"frames: every frame needs uv for the {V} cameras of image_sizes")
    if focal not in ("single", "separate"):
        raise ValueError(f"focal: expected 'single' or 'separate', got {focal!r}")
    if isinstance(reference, bool) or int(reference) != reference or not 0 <= reference < F:
        raise ValueError(f"reference: expected a frame index in [0, {F}), got {reference!r}")
    T_ref = np.eye(4) if T_lab_from_reference is None else as_float_array(
        T_lab_from_reference, "T_lab_from_reference", shape=(4, 4))
    sigma = positive(pixel_sigma, "pixel_sigma")
    if loss not in ("linear", "huber", "soft_l1", "cauchy"):
        raise ValueError(f"loss: expected linear, huber, soft_l1 or cauchy, got {loss!r}")
    positive(loss_scale, "loss_scale")
    px = [None] * V if pixel_size is None else (
        [positive(pixel_size, "pixel_size")] * V if np.ndim(pixel_size) == 0 else list(pixel_size))
    if len(px) != V:
        raise ValueError(f"pixel_size: expected one value or {V}, got {pixel_size!r}")
    fixed_pp = _per_camera(fixed_principal_point, V, "fixed_principal_point", _pp)
    sids = _per_camera(sid_prior, V, "sid_prior", _sid)
    priors = []
    for c in range(V):
        if sids[c] is not None and px[c] is None:
            raise ValueError(f"pixel_size: needed for camera {c + 1}'s sid_prior")
        priors.append(None if sids[c] is None else (sids[c][0], px[c], sids[c][1]))
    # observability
    for c in range(V):
        if not any(np.isfinite(fr.uv[c, :, 0]).any() for fr in frames):
            return _failure(f"camera {c + 1}: no detections in any frame", V, F)
    # initial guess
    sid_f = [None if p is None else p[0] / p[1] for p in priors]
    if initial is not None:
        if not isinstance(initial, Rig) or len(initial) != V:
            raise ValueError(f"initial: expected a Rig of {V} cameras")
        intr, rel = init.from_rig(initial)
        notes = []
    else:
        intr, notes = init.from_dlt(frames, sizes, fixed_pp, sid_f)
        if notes:
            return _failure("; ".join(notes), V, F)
        view_poses = init.poses_with_intrinsics(frames, intr)
        rel, notes = init.relative_poses(view_poses)
        if notes:
            return _failure("; ".join(notes), V, F)
    for c in range(V):
        if fixed_pp[c] is not None:
            intr[c, 2:] = fixed_pp[c]
    view_poses = init.poses_with_intrinsics(frames, intr)
    poses = init.frame_poses(view_poses, rel)
    lost = [f for f in range(F) if not np.isfinite(poses[f, 0, 0])]
    if reference in lost:
        return _failure(f"reference frame {reference}: fewer than 4 beads seen in every view, its "
                        "pose (the lab frame) cannot be found", V, F)
    if lost:  # frames without a pose carry no information about the rig: drop them
        keep = [f for f in range(F) if f not in lost]
        sub = bundle_adjust([frames[f] for f in keep], sizes, initial=Rig(tuple(
            Camera(make_K(*intr[c]), rel[c, :3, :3], rel[c, :3, 3], *sizes[c]) for c in range(V))),
            reference=keep.index(reference), T_lab_from_reference=T_ref, focal=focal,
            fixed_principal_point=fixed_principal_point, pixel_size=pixel_size, sid_prior=sid_prior,
            pixel_sigma=pixel_sigma, loss=loss, loss_scale=loss_scale, max_rms_px=max_rms_px,
            max_outliers=max_outliers, max_evaluations=max_evaluations)
        return _reindex(sub, keep, F, lost)
    prob = Problem(frames, sizes, focal, fixed_pp, priors, sigma, poses[:, :3, :3], rel[:, :3, :3])
    x0 = prob.pack(intr, rel, poses)
    # LSMR trust-region steps on the sparse Jacobian; tight LSMR tolerances make the steps
    # (nearly) exact, which the strongly correlated focal length / depth needs to converge fast
    sol = least_squares(prob.residuals, x0, jac=prob.jacobian, method="trf", loss=loss,
                        f_scale=float(loss_scale), x_scale="jac", tr_solver="lsmr",
                        tr_options={"atol": 1e-12, "btol": 1e-12}, xtol=1e-10, ftol=1e-10,
                        gtol=1e-10, max_nfev=int(max_evaluations))
    return _result(prob, sol, reference, T_ref, px, max_rms_px, max_outliers)


def _result(prob: Problem, sol, ref, T_ref, px, max_rms_px, max_outliers) -> BundleResult:
    x = sol.x
    n_res = len(sol.fun)
    cams = prob.cameras_lab(x, ref, T_ref, px)
    # derived quantities (focal, principal point, source in the lab) depend on the global
    # parameters and the reference frame's pose
    idx = np.concatenate([np.arange(prob.pose0), prob.pose0 + 6 * ref + np.arange(6)])
    std, sub, s0 = covariance(sol.jac, sol.cost, n_res, prob.pose0, idx)

    def derived(xx):
        out = []
        for cam in prob.cameras_lab(xx, ref, T_ref, px):
            out += [cam.fx, cam.cu, cam.cv, *cam.source]
        return np.array(out)

    g0 = derived(x)
    G = np.zeros((len(g0), len(x)))
    for i in idx:
        h = 1e-6 * max(abs(x[i]), 1.0)
        xp = x.copy()
        xp[i] += h
        G[:, i] = (derived(xp) - g0) / h
    with np.errstate(invalid="ignore"):
        Cg = G[:, idx] @ sub @ G[:, idx].T if np.all(np.isfinite(sub)) else np.full((len(g0),) * 2, np.inf)
    sg = np.sqrt(np.abs(np.diag(Cg)))
    cam_std = []
    for c, cam in enumerate(cams):
        s = sg[6 * c : 6 * c + 6]
        d = {"f": s[0], "cu": s[1], "cv": s[2], "source": s[3:6].copy()}
        if cam.pixel_size is not None:
            d["sid"] = s[0] * cam.pixel_size
        cam_std.append(d)
    res = prob.project(x) - prob.uv
    _, Rc, tc = prob.rel(x)
    _, Rf, tf = prob.poses(x)
    T_lab_from_c1 = T_ref @ _so3.inv(_so3.rigid(Rf[ref], tf[ref]))
    obj = T_lab_from_c1 @ _so3.rigid(Rf, tf)
    err = np.linalg.norm(res, axis=1)
    thr = 5.0 * max(np.median(err) / 1.1774, 0.1 * prob.sigma)
    out = err > thr
    rms = float(np.sqrt(np.mean(err[~out] ** 2)))
    ok, reason = True, ""
    if sol.status <= 0:
        ok, reason = False, f"the optimizer did not converge ({sol.message})"
    elif not rms <= max_rms_px:
        ok, reason = False, (f"reprojection RMS {rms:.3g} px exceeds max_rms_px={max_rms_px:g}: "
                             "mislabelled beads or a wrong initial guess")
    elif out.mean() > max_outliers:
        ok, reason = False, (f"{100 * out.mean():.0f} % of the observations are outliers (more "
                             f"than {5 * max(np.median(err) / 1.1774, 0.1 * prob.sigma):.2g} px off)")
    return BundleResult(ok, reason, Rig(cams) if ok else None, _so3.rigid(Rc, tc), obj, prob.names, x,
                        std, cam_std, prob.of, prob.oc, prob.op, res, out, s0, int(sol.nfev),
                        str(sol.message))


def _reindex(sub: BundleResult, keep: list[int], F: int, lost: list[int]) -> BundleResult:
    """Map a result computed on the frames ``keep`` back to all ``F`` frames."""
    keep_a = np.asarray(keep)
    poses = np.full((F, 4, 4), np.nan)
    if sub.object_poses.size:
        poses[keep_a] = sub.object_poses
    names = tuple(n if not n.startswith("frame") else
                  f"frame{keep[int(n[5:n.index('.')])]}{n[n.index('.'):]}" for n in sub.parameter_names)
    note = f"frames {lost} dropped (fewer than 4 beads in every view)"
    reason = f"{sub.reason}; {note}" if sub.reason else ""
    return BundleResult(sub.ok, reason, sub.rig, sub.relative_poses, poses, names, sub.parameters,
                        sub.std, sub.camera_std, keep_a[sub.frame_index] if sub.frame_index.size
                        else sub.frame_index, sub.view, sub.point_index, sub.residuals, sub.outliers,
                        sub.sigma0, sub.n_evaluations, f"{sub.message} ({note})")
