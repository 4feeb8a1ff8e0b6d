"""Model of the rigid-rig bundle adjustment: parameter layout, residuals, analytic sparse
Jacobian and the parameter covariance (private to :mod:`core.calibration.bundle`)."""

from __future__ import annotations

import numpy as np
import scipy.sparse

from ..geometry.camera import Camera, make_K
from . import _so3


class Problem:
    """Parameter layout, residuals and analytic Jacobian (one instance per call)."""

    def __init__(self, frames, sizes, focal, fixed_pp, priors, sigma, R0f, R0c):
        self.V, self.F = len(sizes), len(frames)
        self.sizes, self.fixed_pp, self.priors, self.sigma = sizes, fixed_pp, priors, sigma
        self.R0f, self.R0c = R0f, R0c
        names, ix = [], []
        for c in range(self.V):
            k = f"cam{c + 1}"
            i_fx = len(names)
            names += [f"{k}.fx"] if focal == "separate" else [f"{k}.f"]
            i_fy = len(names) if focal == "separate" else i_fx
            if focal == "separate":
                names.append(f"{k}.fy")
            i_cu = i_cv = -1
            if fixed_pp[c] is None:
                i_cu, i_cv = len(names), len(names) + 1
                names += [f"{k}.cu", f"{k}.cv"]
            ix.append((i_fx, i_fy, i_cu, i_cv))
        self.ix = np.array(ix)
        self.rel0 = len(names)
        for c in range(1, self.V):
            names += [f"cam{c + 1}_from_cam1.{a}" for a in ("rx", "ry", "rz", "tx", "ty", "tz")]
        self.pose0 = len(names)
        for f in range(self.F):
            names += [f"frame{f}.{a}" for a in ("rx", "ry", "rz", "tx", "ty", "tz")]
        self.names = tuple(names)
        # observations
        fi, vi, pi, X, uv = [], [], [], [], []
        for f, fr in enumerate(frames):
            for c in range(self.V):
                seen = np.flatnonzero(np.isfinite(fr.uv[c, :, 0]))
                fi.append(np.full(len(seen), f))
                vi.append(np.full(len(seen), c))
                pi.append(seen)
                X.append(fr.points[seen])
                uv.append(fr.uv[c, seen])
        self.of, self.oc, self.op = (np.concatenate(a).astype(np.int64) for a in (fi, vi, pi))
        self.X, self.uv = np.concatenate(X), np.concatenate(uv)
        self.M = len(self.of)
        self.prior_cams = [c for c in range(self.V) if priors[c] is not None]

    # -- unpacking
    def intrinsics(self, x):
        out = np.empty((self.V, 4))
        for c, (a, b, u, v) in enumerate(self.ix):
            out[c, 0], out[c, 1] = x[a], x[b]
            out[c, 2:] = (x[u], x[v]) if u >= 0 else self.fixed_pp[c]
        return out

    def rel(self, x):
        w = np.zeros((self.V, 3))
        t = np.zeros((self.V, 3))
        if self.V > 1:
            p = x[self.rel0 : self.pose0].reshape(-1, 6)
            w[1:], t[1:] = p[:, :3], p[:, 3:]
        return w, _so3.exp(w) @ self.R0c, t

    def poses(self, x):
        p = x[self.pose0 :].reshape(-1, 6)
        return p[:, :3], _so3.exp(p[:, :3]) @ self.R0f, p[:, 3:]

    def pack(self, intr, rel, poses) -> np.ndarray:
        """Parameter vector at the initial guess (ω = 0; R₀ from ``rel``/``poses``)."""
        x = np.zeros(len(self.names))
        for c, (a, b, u, v) in enumerate(self.ix):
            x[a], x[b] = (intr[c, 0], intr[c, 1]) if a != b else (0.5 * (intr[c, 0] + intr[c, 1]),) * 2
            if u >= 0:
                x[u], x[v] = intr[c, 2:]
        for c in range(1, self.V):
            x[self.rel0 + 6 * (c - 1) + 3 : self.rel0 + 6 * c] = rel[c, :3, 3]
        x[self.pose0 :] = np.concatenate([np.zeros((self.F, 3)), poses[:, :3, 3]], axis=1).ravel()
        return x

    # -- model
    def _forward(self, x):
        K = self.intrinsics(x)
        wc, Rc, tc = self.rel(x)
        wf, Rf, tf = self.poses(x)
        Xf = np.einsum("mij,mj->mi", Rf[self.of], self.X)
        p1 = Xf + tf[self.of]
        Xc = np.einsum("mij,mj->mi", Rc[self.oc], p1)
        pc = Xc + tc[self.oc]
        return K, wc, Rc, wf, Xf, Xc, pc

    def project(self, x) -> np.ndarray:
        K, *_, pc = self._forward(x)
        k = K[self.oc]
        return np.column_stack([k[:, 0] * pc[:, 0] / pc[:, 2] + k[:, 2],
                                k[:, 1] * pc[:, 1] / pc[:, 2] + k[:, 3]])

    def residuals(self, x) -> np.ndarray:
        r = ((self.project(x) - self.uv) / self.sigma).ravel()
        if not self.prior_cams:
            return r
        K = self.intrinsics(x)
        pr = [(0.5 * (K[c, 0] + K[c, 1]) * self.priors[c][1] - self.priors[c][0]) / self.priors[c][2]
              for c in self.prior_cams]
        return np.concatenate([r, pr])

    def jacobian(self, x):
        K, wc, Rc, wf, Xf, Xc, pc = self._forward(x)
        k = K[self.oc]
        z = pc[:, 2]
        xz, yz = pc[:, 0] / z, pc[:, 1] / z
        A = np.zeros((self.M, 2, 3))  # d(u, v)/d pc
        A[:, 0, 0] = k[:, 0] / z
        A[:, 0, 2] = -k[:, 0] * xz / z
        A[:, 1, 1] = k[:, 1] / z
        A[:, 1, 2] = -k[:, 1] * yz / z
        A /= self.sigma
        rows0 = 2 * np.arange(self.M)
        R, C, D = [], [], []

        def add(rows, cols, vals):
            keep = cols >= 0
            R.append(rows[keep])
            C.append(cols[keep])
            D.append(vals[keep])

        ixc = self.ix[self.oc]
        add(rows0, ixc[:, 0], xz / self.sigma)
        add(rows0 + 1, ixc[:, 1], yz / self.sigma)
        add(rows0, ixc[:, 2], np.full(self.M, 1 / self.sigma))
        add(rows0 + 1, ixc[:, 3], np.full(self.M, 1 / self.sigma))
        # rig
        m1 = np.flatnonzero(self.oc > 0)
        if m1.size:
            Jw = -_so3.hat(Xc[m1]) @ _so3.left_jacobian(wc[self.oc[m1]])
            blk = np.concatenate([A[m1] @ Jw, A[m1]], axis=2)  # (m, 2, 6)
            cols = self.rel0 + 6 * (self.oc[m1] - 1)
            self._block(add, rows0[m1], cols, blk)
        # frame poses
        Jw = -_so3.hat(Xf) @ _so3.left_jacobian(wf[self.of])
        ARc = A @ Rc[self.oc]
        blk = np.concatenate([ARc @ Jw, ARc], axis=2)
        self._block(add, rows0, self.pose0 + 6 * self.of, blk)
        n_rows = 2 * self.M
        for j, c in enumerate(self.prior_cams):
            _, px, tol = self.priors[c]
            a, b = self.ix[c, :2]
            if a == b:
                add(np.array([n_rows + j]), np.array([a]), np.array([px / tol]))
            else:
                add(np.array([n_rows + j] * 2), np.array([a, b]), np.array([0.5 * px / tol] * 2))
        shape = (n_rows + len(self.prior_cams), len(self.names))
        return scipy.sparse.csr_matrix((np.concatenate(D), (np.concatenate(R), np.concatenate(C))),
                                       shape=shape)

    @staticmethod
    def _block(add, rows, cols, blk):
        m = len(rows)
        rr = np.repeat(np.stack([rows, rows + 1], 1)[:, :, None], 6, axis=2)
        cc = np.broadcast_to(cols[:, None, None] + np.arange(6), (m, 2, 6))
        add(rr.ravel(), cc.ravel(), blk.ravel())

    # -- outputs
    def cameras_lab(self, x, ref: int, T_lab_from_ref: np.ndarray, pixel_size) -> tuple[Camera, ...]:
        K = self.intrinsics(x)
        _, Rc, tc = self.rel(x)
        _, Rf, tf = self.poses(x)
        T_c1_from_lab = _so3.rigid(Rf[ref], tf[ref]) @ _so3.inv(T_lab_from_ref)
        cams = []
        for c in range(self.V):
            T = _so3.rigid(Rc[c], tc[c]) @ T_c1_from_lab
            w, h = self.sizes[c]
            cams.append(Camera(make_K(*K[c]), T[:3, :3], T[:3, 3], w, h, pixel_size[c], f"cam{c + 1:02d}"))
        return tuple(cams)


def _pinv_sym(N: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Inverse of a symmetric PSD matrix (Jacobi-scaled eigen-decomposition) and a mask of the
    parameters touched by its null space (unobservable: infinite variance)."""
    d = np.sqrt(np.maximum(np.diag(N), 1e-300))
    w, U = np.linalg.eigh(N / d[:, None] / d[None])
    bad = w <= 1e-12 * max(w.max(), 1e-300)
    winv = np.where(bad, 0.0, 1.0 / np.where(bad, 1.0, w))
    null = np.any(np.abs(U[:, bad]) > 1e-6, axis=1) if bad.any() else np.zeros(len(N), bool)
    return (U * winv) @ U.T / d[:, None] / d[None], null


def covariance(J, cost: float, m: int, p0: int, keep: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """Standard deviations of all parameters and the covariance of the parameters ``keep``
    (global ones and one frame block), ``s² (JᵀJ)⁻¹``, by the Schur complement of the
    block-diagonal frame-pose part (6 x 6 per frame): cheap for many frames."""
    n = J.shape[1]
    s2 = 2.0 * cost / max(m - n, 1)
    JtJ = (J.T @ J).tocsr() if scipy.sparse.issparse(J) else scipy.sparse.csr_matrix(J.T @ J)
    A = JtJ[:p0, :p0].toarray()
    B = JtJ[:p0, p0:].toarray()
    F = (n - p0) // 6
    Dinv = np.zeros((F, 6, 6))
    dnull = np.zeros((F, 6), bool)
    for f in range(F):
        sl = slice(p0 + 6 * f, p0 + 6 * f + 6)
        Dinv[f], dnull[f] = _pinv_sym(JtJ[sl, sl].toarray())
    Bf = B.reshape(p0, F, 6).transpose(1, 0, 2)  # (F, p0, 6)
    BD = Bf @ Dinv  # (F, p0, 6)
    S = A - np.einsum("fij,fkj->ik", BD, Bf)
    Sinv, snull = _pinv_sym(S) if p0 else (np.zeros((0, 0)), np.zeros(0, bool))
    # frame blocks: D⁻¹ + D⁻¹ Bᵀ S⁻¹ B D⁻¹ ; cross terms global-frame: -S⁻¹ B D⁻¹
    cross = -np.einsum("ij,fjk->fik", Sinv, BD)  # (F, p0, 6)
    blocks = Dinv + np.einsum("fji,jk,fkl->fil", BD, Sinv, BD)
    var = np.concatenate([np.diag(Sinv), np.einsum("fii->fi", blocks).ravel()]) * s2
    var[np.concatenate([snull, dnull.ravel()])] = np.inf
    if snull.any():  # an unobservable rig parameter makes every pose uncertain too
        var[p0:] = np.inf
    full = lambda i, j: (Sinv[i, j] if i < p0 and j < p0 else  # noqa: E731
                         cross[(j - p0) // 6, i, (j - p0) % 6] if i < p0 else
                         cross[(i - p0) // 6, j, (i - p0) % 6] if j < p0 else
                         blocks[(i - p0) // 6, (i - p0) % 6, (j - p0) % 6] if (i - p0) // 6 == (j - p0) // 6
                         else np.nan)
    sub = np.array([[full(i, j) for j in keep] for i in keep]) * s2
    if not np.all(np.isfinite(var[keep])):
        sub[:] = np.inf
    return np.sqrt(var), sub, float(np.sqrt(s2))
