"""Cramér–Rao lower bound of a bone's pose from one biplane frame.

How precisely can *any* per-frame registration place a bone, given the photons that reached the
detector? The bound answers that from the imaging physics, independently of the cost function
and the optimiser, so the tracker's per-frame errors can be compared with what the images allow.

Model (the quantum stage of :class:`core.synthetic.ImagingModel`): pixel ``p`` of view ``v``
detects ``n_p ~ Poisson(N_v · exp(-L_p(θ)))`` quanta, ``L`` being the line integral of everything
in the beam (the bone at pose ``θ`` plus the other bones, soft tissue, walkway) and ``N_v`` the
quanta per pixel at full fluence. The views are independent, so the Fisher information is

    J(θ) = Σ_v Σ_p N_v · exp(-L_p) · ∂L_p/∂θ · ∂L_p/∂θᵀ

and every unbiased estimator of ``θ`` from that frame has covariance ``⪰ J⁻¹``. ``θ`` is the
registration's parameter vector (:class:`core.tracking.cost.RegistrationCost`): displacement of
the rotation centre in the lab (mm) and a rotation vector about lab axes through it (degrees),
the axes in which :func:`core.studies.tracking.acceptance.pose_errors` reports errors.

The intensifier blur, glare, roll-off and distortion that follow the quantum stage are
invertible linear maps of the detected image: with no noise after them they neither add nor
remove information. Camera read noise and quantisation (small next to the quantum noise) are
left out. Both choices make ``J`` larger, so the bound stays a *lower* bound — optimistic.
:func:`pose_bound` takes the other bones as known, which is optimistic too: no tracker knows them,
in joint or in sequential mode all ``6 n`` parameters of the frame's ``n`` bones are estimated from
the same images. :func:`joint_bound` gives the bound of that problem: the ``(6 n, 6 n)`` information
of all the bones' poses (the same sum, ``∂L/∂θ_a · ∂L/∂θ_bᵀ`` for every pair of bones, which is not
zero where their projections overlap), whose inverse's ``b`` block is bone ``b``'s bound — the
inverse of the Schur complement ``J_bb − J_bo J_oo⁻¹ J_ob``, never below :func:`pose_bound`'s
``J_bb⁻¹`` and equal to it where the bone's projection overlaps no other's. On the acceptance trial
(1024², one NVIDIA H100) the two differ by less than 0.1 % for every bone:
:mod:`core.studies.tracking.joint_bound`.

``∂L/∂θ`` is the bone's DRR (:class:`core.render.DRRRenderer`, the renderer that synthesises the
study's frames) differentiated by central differences. It must be the volume the frames were
rendered from, under the transfer they were rendered with — not a tracker's model of it: a CT that
is the truth blurred, resampled and noisy changes less with the pose, so its bound is too large. On
the harder trial (:mod:`core.studies.tracking.hard_trial`, 192², 1 mm, this 2-core CPU machine)
the tracker's CT gave a talus bound 1.6× the truth's, which an oracle maximum-likelihood fit on
Poisson frames beat (0.59 / 0.57× it; 0.94 / 0.92× the truth's):
:mod:`core.studies.tracking.hard_bound_check`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

__all__ = ["JointBound", "PoseBound", "joint_bound", "pose_bound"]


@dataclass(frozen=True)
class PoseBound:
    """Fisher information and Cramér–Rao bound of one bone's 6 pose parameters (mm, degrees).

    Attributes
    ----------
    information : (6, 6) array
        ``J`` in units of 1/mm² (translation block) and 1/deg² (rotation block).
    covariance : (6, 6) array
        ``J⁻¹``: the smallest covariance an unbiased per-frame estimator can have.
    sigma : (6,) array
        Square roots of its diagonal (mm ×3, degrees ×3).
    rms_mm, rms_deg : float
        ``sqrt(trace)`` of the translation and rotation blocks: the least RMS length of the
        centroid error vector (mm) and of the rotation error vector (degrees).
    pixels : int
        Pixels (both views) in which the bone's projection changes with its pose.
    """

    information: np.ndarray
    covariance: np.ndarray
    sigma: np.ndarray
    rms_mm: float
    rms_deg: float
    pixels: int

    def to_dict(self) -> dict:
        return {"sigma": self.sigma.tolist(), "rms_mm": self.rms_mm, "rms_deg": self.rms_deg,
                "pixels": self.pixels}


def _per_view(value, n: int, name: str) -> list[float]:
    vals = np.asarray(value, dtype=float)
    if vals.ndim == 0:
        vals = np.full(n, float(vals))
    if vals.shape != (n,) or not np.all(np.isfinite(vals)) or np.any(vals <= 0):
        raise ValueError(f"{name}: expected a positive number or one per view ({n}), got {value!r}")
    return [float(v) for v in vals]


def _derivatives(renderer, bone, pose, center, *, line_integral, quanta_per_pixel, views, step, margin_px):
    """``(views, N, [(view, roi, dL/dθ (6, h, w), L (h, w)), …])`` of the views the bone is seen in."""
    from .cost import OutsideViewError, search_roi

    views = tuple(range(len(renderer.cameras))) if views is None else tuple(int(v) for v in views)
    n_cam = len(renderer.cameras)
    L = list(line_integral)
    if len(L) != n_cam:
        raise ValueError(f"line_integral: expected {n_cam} images (one per camera), got {len(L)}")
    N = _per_view(quanta_per_pixel, n_cam, "quanta_per_pixel")
    pose = np.asarray(pose, dtype=float)
    center = np.asarray(center, dtype=float)
    if pose.shape != (4, 4) or center.shape != (3,):
        raise ValueError(f"pose, center: expected (4, 4) and (3,), got {pose.shape} and {center.shape}")
    if not (np.all(np.isfinite(pose)) and np.all(np.isfinite(center))):
        raise ValueError(f"pose, center: expected finite values for bone {bone}")
    h_mm, h_deg = (float(s) for s in step)
    if not (h_mm > 0 and h_deg > 0):
        raise ValueError(f"step: expected positive (mm, degrees), got {step!r}")
    from ..geometry.transforms import pose_from_params

    roi = np.zeros((len(views), 4), dtype=np.int64)
    used = []
    for i, v in enumerate(views):  # a bone seen in one view only still has a (weaker) bound
        try:
            roi[i] = search_roi(renderer, pose, bone, views=[v], center=center, reach_mm=0.0,
                                margin_px=margin_px)[0]
            used.append(i)
        except OutsideViewError:
            pass
    if not used:
        raise OutsideViewError(f"bone {bone}: its projection misses every view {views}")
    h = np.array([h_mm] * 3 + [h_deg] * 3)
    X = np.concatenate([np.diag(h), -np.diag(h)])  # (12, 6): +h_k then -h_k
    P = pose_from_params(np.concatenate([X[:, :3], np.radians(X[:, 3:])], axis=1), center=center, base=pose)
    vsel = [views[i] for i in used]
    batch = renderer.render(P[:, None], views=vsel, bones=[bone], roi=roi[used][None, :, None, :])
    img = batch.numpy()[:, :, 0]  # (12, n_used, H, W)
    out = []
    for j, i in enumerate(used):
        v = views[i]
        u0, v0, w, hh = (int(a) for a in roi[i])
        Lv = np.asarray(L[v], dtype=float)
        if Lv.shape != tuple(renderer.cameras[v].image_shape):
            raise ValueError(f"line_integral[{v}]: expected shape {tuple(renderer.cameras[v].image_shape)}, "
                             f"got {Lv.shape}")
        Lr = Lv[v0:v0 + hh, u0:u0 + w]
        if not np.all(np.isfinite(Lr)):
            raise ValueError(f"line_integral[{v}]: expected finite values where bone {bone} projects")
        D = (img[:6, j, :hh, :w] - img[6:, j, :hh, :w]).astype(float) / (2 * h[:, None, None])  # (6, h, w)
        out.append((v, (u0, v0, w, hh), D, Lr))
    return views, N, out


def pose_bound(renderer, bone: int, pose, center, *, line_integral: Sequence[np.ndarray],
               quanta_per_pixel, views: Sequence[int] | None = None, step=(0.1, 0.1),
               margin_px: int = 6) -> PoseBound:
    """Cramér–Rao bound of ``bone``'s pose in one frame (see the module docstring).

    Parameters
    ----------
    renderer : core.render.DRRRenderer
        Holds the bone's attenuation volume (index ``bone``) and the cameras: the volume and
        transfer the frames were rendered from (module docs), not the tracker's CT.
    pose : (4, 4) array
        The true ``T_lab_from_bone``.
    center : (3,) array
        Rotation centre in the bone's CT frame (its centroid), mm.
    line_integral : sequence of (H, W) arrays
        Total line integral ``L`` of each camera's image (all of ``renderer.cameras``) at this
        frame: what sets the quanta behind each pixel.
    quanta_per_pixel : float or sequence of float
        Detected quanta per pixel at full fluence (``L = 0``), per view or one for all.
    views : sequence of int, optional
        Views used (default all).
    step : (mm, degrees)
        Central-difference steps.
    margin_px : int
        Pixels around the bone's projected box that are included.

    Raises
    ------
    core.tracking.cost.OutsideViewError
        The bone projects outside every used view.
    ValueError
        Bad shapes or values (named in the message).
    """
    views, N, D = _derivatives(renderer, bone, pose, center, line_integral=line_integral,
                               quanta_per_pixel=quanta_per_pixel, views=views, step=step, margin_px=margin_px)
    J = np.zeros((6, 6))
    pixels = 0
    for v, _, Dv, Lv in D:
        q = N[v] * np.exp(-Lv)
        G = Dv.reshape(6, -1)
        J += (G * q.ravel()) @ G.T
        pixels += int(np.count_nonzero(np.any(Dv != 0, axis=0)))
    return _from_covariance(J, _inverse(J), pixels)


def _inverse(J: np.ndarray) -> np.ndarray:
    """``J⁻¹`` of a symmetric information matrix; all ``inf`` where it is singular."""
    w, V = np.linalg.eigh(0.5 * (J + J.T))
    if np.all(np.isfinite(w)) and w.max() > 0 and w.min() > 1e-12 * w.max():
        return (V / w) @ V.T  # symmetric positive definite by construction
    # some combination of parameters leaves the images unchanged: no finite bound
    return np.full(J.shape, np.inf)


def _blockwise_inverse(J: np.ndarray, n: int) -> np.ndarray:
    """``J⁻¹`` of ``n`` bones' ``(6 n, 6 n)`` information, inverted per group of bones linked by
    non-zero cross blocks (bones whose regions meet, directly or through others): a group whose
    information is singular gets ``inf`` (:func:`_inverse`) without taking the other groups' finite
    bounds with it; between groups the covariance is zero."""
    linked = [[c for c in range(n) if c != a and np.any(J[6 * a:6 * a + 6, 6 * c:6 * c + 6] != 0)]
              for a in range(n)]
    C = np.zeros_like(J)
    seen: set[int] = set()
    for a in range(n):
        if a in seen:
            continue
        group, todo = [], [a]
        seen.add(a)
        while todo:
            k = todo.pop()
            group.append(k)
            for c in linked[k]:
                if c not in seen:
                    seen.add(c)
                    todo.append(c)
        idx = np.concatenate([np.arange(6 * k, 6 * k + 6) for k in sorted(group)])
        C[np.ix_(idx, idx)] = _inverse(J[np.ix_(idx, idx)])
    return C


def _from_covariance(J: np.ndarray, C: np.ndarray, pixels: int) -> PoseBound:
    sig = np.sqrt(np.diag(C))
    return PoseBound(information=J, covariance=C, sigma=sig, rms_mm=float(np.sqrt(np.trace(C[:3, :3]))),
                     rms_deg=float(np.sqrt(np.trace(C[3:, 3:]))), pixels=pixels)


@dataclass(frozen=True)
class JointBound:
    """Cramér–Rao bound of several bones' poses estimated together from one frame
    (:func:`joint_bound`).

    Attributes
    ----------
    bones : tuple of int
        The bones in the joint problem (volume indices), in the order of the blocks below.
    information, covariance : (6 n, 6 n) arrays
        The Fisher information of all the bones' parameters (bone ``k``'s at rows ``6k … 6k+5``,
        mm then degrees as in :class:`PoseBound`) and its inverse, taken per group of bones whose
        regions meet: ``inf`` over a group whose information is singular (some combination of its
        parameters leaves the images unchanged), the other groups' blocks finite.
    joint : tuple of PoseBound
        Per bone, the bound with the other bones unknown: ``covariance`` the bone's block of the
        joint covariance, ``information`` its inverse (the Schur complement).
    known : tuple of PoseBound
        Per bone, the bound with the other bones known (:func:`pose_bound`: its own 6×6 block).
    missing : tuple of int
        Bones left out because their projection misses every view (no pixel, no information).
    """

    bones: tuple[int, ...]
    information: np.ndarray
    covariance: np.ndarray
    joint: tuple[PoseBound, ...]
    known: tuple[PoseBound, ...]
    missing: tuple[int, ...] = ()

    def ratio(self) -> np.ndarray:
        """``(n, 2)``: per bone the joint bound over the known-others bound, mm and degrees."""
        return np.array([[j.rms_mm / k.rms_mm, j.rms_deg / k.rms_deg] for j, k in zip(self.joint, self.known,
                                                                                     strict=True)])

    def to_dict(self) -> dict:
        return {"bones": list(self.bones), "missing": list(self.missing),
                "joint": [b.to_dict() for b in self.joint], "known": [b.to_dict() for b in self.known]}


def joint_bound(renderer, bones: Sequence[int], poses, centers, *, line_integral: Sequence[np.ndarray],
                quanta_per_pixel, views: Sequence[int] | None = None, step=(0.1, 0.1),
                margin_px: int = 6) -> JointBound:
    """Cramér–Rao bound of ``bones``' poses estimated together from one frame (module docs).

    The ``(6 n, 6 n)`` information is :func:`pose_bound`'s sum over every pair of bones and every
    pixel both bones' regions cover in a view; its diagonal blocks are :func:`pose_bound`'s
    information exactly. Bones whose projection misses every used view are left out of the problem
    (``missing``): they add no pixel, so they change no other bone's bound. A bone with no finite
    bound (singular information) leaves ``inf`` only to the bones whose regions meet its own
    (directly or through others); the rest keep theirs.

    Parameters
    ----------
    bones : sequence of int
        Volume indices of ``renderer`` estimated in the frame.
    poses : (n, 4, 4) array
        Their true ``T_lab_from_bone``.
    centers : (n, 3) array
        Their rotation centres in their CT frames (centroids), mm.
    line_integral, quanta_per_pixel, views, step, margin_px
        As :func:`pose_bound`.

    Raises
    ------
    core.tracking.cost.OutsideViewError
        Every bone projects outside every used view.
    ValueError
        Bad shapes or values (named in the message).
    """
    from .cost import OutsideViewError

    bones = tuple(int(b) for b in bones)
    poses = np.asarray(poses, dtype=float)
    centers = np.asarray(centers, dtype=float)
    if not bones or poses.shape != (len(bones), 4, 4) or centers.shape != (len(bones), 3):
        raise ValueError(f"bones, poses, centers: expected n >= 1 bones, (n, 4, 4) and (n, 3), got "
                         f"{len(bones)}, {poses.shape} and {centers.shape}")
    if len(set(bones)) != len(bones):
        raise ValueError(f"bones: expected distinct indices, got {bones}")
    kept, missing, D = [], [], []
    for k, b in enumerate(bones):
        try:
            _, N, Db = _derivatives(renderer, b, poses[k], centers[k], line_integral=line_integral,
                                    quanta_per_pixel=quanta_per_pixel, views=views, step=step,
                                    margin_px=margin_px)
        except OutsideViewError:
            missing.append(b)
            continue
        kept.append(b)
        D.append(Db)
    if not kept:
        raise OutsideViewError(f"bones {bones}: every projection misses every view")
    q = {}  # per view, the quanta behind each pixel: N e^{-L}
    n = len(kept)
    J = np.zeros((6 * n, 6 * n))
    for a in range(n):
        for c in range(a, n):
            blk = np.zeros((6, 6))
            for va, (ua, ya, wa, ha), Da, _ in D[a]:
                for vc, (uc, yc, wc, hc), Dc, _ in D[c]:
                    if va != vc:
                        continue
                    x0, x1 = max(ua, uc), min(ua + wa, uc + wc)
                    y0, y1 = max(ya, yc), min(ya + ha, yc + hc)
                    if x1 <= x0 or y1 <= y0:
                        continue
                    if va not in q:
                        q[va] = N[va] * np.exp(-np.asarray(line_integral[va], dtype=float))
                    Ga = Da[:, y0 - ya:y1 - ya, x0 - ua:x1 - ua].reshape(6, -1)
                    Gc = Dc[:, y0 - yc:y1 - yc, x0 - uc:x1 - uc].reshape(6, -1)
                    blk += (Ga * q[va][y0:y1, x0:x1].ravel()) @ Gc.T
            J[6 * a:6 * a + 6, 6 * c:6 * c + 6] = blk
            J[6 * c:6 * c + 6, 6 * a:6 * a + 6] = blk.T
    C = _blockwise_inverse(J, n)
    joint, known = [], []
    for k in range(n):
        s = slice(6 * k, 6 * k + 6)
        pixels = sum(int(np.count_nonzero(np.any(Dv != 0, axis=0))) for _, _, Dv, _ in D[k])
        Jk = J[s, s]
        known.append(_from_covariance(Jk, _inverse(Jk), pixels))
        Ck = C[s, s]
        Jm = _inverse(Ck) if np.all(np.isfinite(Ck)) else np.zeros((6, 6))  # the Schur complement
        joint.append(_from_covariance(Jm, Ck, pixels))
    return JointBound(bones=tuple(kept), information=J, covariance=C, joint=tuple(joint), known=tuple(known),
                      missing=tuple(missing))


def chain_information(renderer, bone: int, pose, center, *, line_integral: Sequence[np.ndarray],
                      quanta_per_pixel, psf, added_noise, contrast=1.0, views: Sequence[int] | None = None,
                      step=(0.1, 0.1), margin_px: int | None = None, tol: float = 1e-8,
                      max_iter: int = 2000) -> np.ndarray:
    """``(6, 6)`` Fisher information of ``bone``'s pose when the quanta are blurred and then
    meet noise that the blur did not shape (read noise, quantisation): what a frame holds after
    the whole chain, not only at the quantum stage (:func:`pose_bound`).

    Per view the detected image, in quanta, is ``y = K q + e``: ``q ~ Poisson(λ)``, ``λ = N
    e^{-L}``, ``K`` the PSF (``psf``: one normalised odd kernel, or one per view), carrying the
    fraction ``contrast`` of the light (the rest spread far, e.g. veiling glare: it is left out,
    so the information is that of ``contrast · K q``), and ``e`` white noise of σ ``added_noise``
    (quanta at full fluence, one per view or one for all). In the Gaussian approximation
    ``J = Gᵀ C⁻¹ G`` with ``G = K (λ ∂L/∂θ)`` and ``C = K Λ Kᵀ + (σ/contrast)² I``; ``C⁻¹ G`` by
    preconditioned conjugate gradients over the bone's region (grown by the kernel's radius). With
    ``K`` = identity and ``σ`` = 0 this is :func:`pose_bound`'s information. Gaussian kernels
    attenuate high spatial frequencies; the added noise then hides them, which is why a blurred,
    read-out frame holds less than the quantum stage alone.
    """
    import cv2

    n_cam = len(renderer.cameras)
    ks = list(psf) if (isinstance(psf, (list, tuple)) or np.ndim(psf) == 3) else [psf] * n_cam
    if len(ks) != n_cam:
        raise ValueError(f"psf: expected one kernel or one per camera ({n_cam})")
    ks = [np.asarray(k, np.float64) / np.sum(k) for k in ks]
    for k in ks:
        if k.ndim != 2 or k.shape[0] % 2 == 0 or k.shape[1] % 2 == 0:
            raise ValueError(f"psf: expected odd-sized 2-D kernels, got shape {k.shape}")
    sig = np.broadcast_to(np.asarray(added_noise, dtype=float), (n_cam,))
    con = np.broadcast_to(np.asarray(contrast, dtype=float), (n_cam,))
    if np.any(sig < 0) or np.any(con <= 0):
        raise ValueError("added_noise, contrast: expected added_noise >= 0 and contrast > 0")
    if margin_px is None:
        margin_px = 6 + max(k.shape[0] for k in ks) // 2
    views, N, D = _derivatives(renderer, bone, pose, center, line_integral=line_integral,
                               quanta_per_pixel=quanta_per_pixel, views=views, step=step, margin_px=margin_px)
    J = np.zeros((6, 6))
    for v, _, Dv, Lv in D:
        k = ks[v]

        def conv(a, k=k):
            return cv2.filter2D(a, -1, k[::-1, ::-1], borderType=cv2.BORDER_CONSTANT)

        lam = N[v] * np.exp(-Lv)
        s2 = float(sig[v] / con[v]) ** 2
        G = np.stack([conv(lam * Dv[i]) for i in range(6)])
        pre = 1.0 / (cv2.filter2D(lam, -1, (k * k)[::-1, ::-1], borderType=cv2.BORDER_CONSTANT) + s2)

        def C(x, k=k, lam=lam, s2=s2, conv=conv):
            return conv(lam * conv(x)) + s2 * x

        for i in range(6):  # preconditioned conjugate gradients, one right-hand side at a time
            b = G[i]
            x = b * pre
            r = b - C(x)
            z = r * pre
            p = z.copy()
            rz = float(np.sum(r * z))
            bb = float(np.sum(b * b * pre))
            for _ in range(max_iter):
                Cp = C(p)
                a = rz / float(np.sum(p * Cp))
                x += a * p
                r -= a * Cp
                z = r * pre
                rz_new = float(np.sum(r * z))
                if rz_new <= tol * bb:
                    break
                p = z + (rz_new / rz) * p
                rz = rz_new
            J[i] += np.einsum("kij,ij->k", G, x)
    return 0.5 * (J + J.T)
