"""The local fits of a bone's trajectory that the review flags of :mod:`core.tracking.flags_post`,
:mod:`core.tracking.flags_gaps` and :mod:`core.tracking.flags_pairs` judge frames by (the module docs of
:mod:`core.tracking.flags_post` say how): the poses' parameters about each frame of its neighbours, and a
frame's normalised residual against the polynomial through the neighbours in use; and the names the
rules' messages start with."""

from __future__ import annotations

import math

import numpy as np

__all__ = ["ALIKE", "ENDS", "FLAG", "UNCHECKED"]

#: The flag's name (the message starts with it).
FLAG = "off the trajectory"
#: The note (not a flag) of a good frame the check could not judge: no fit within :data:`REACH`.
UNCHECKED = "trajectory unchecked"
#: A frame within ``half_window`` tracked frames of a trial's first or last frame with a pose is fitted
#: through the frames of its window shifted inside the trial (``2 * half_window`` wide), not the window
#: cut at the end (the ``ends`` keyword's default of :func:`core.tracking.flags_post.trajectory_review`;
#: False: cut, the check before; :mod:`core.tracking.flags_post`'s docs, *A trial's ends*).
ENDS = True
#: The fits' arithmetic shared (exact: the same residuals to the bit, so the same flags and notes; False:
#: as before, for the test that says so): :meth:`_Table._factor` takes every frame offset's deltas from
#: one batch, where it computed them again for each set of offsets, and a set of offsets' weights
#: (:meth:`_Table._weights`) are kept for every table (:data:`_WEIGHTS`), not solved again per table.
#: The check of a 100-frame bone took 23 ms at the end of a one-bone run on one NVIDIA H100's host; on
#: this 2-core x86_64 machine (shared), over the 18 bones of the acceptance runs at b941103 (seeds 0, 3
#: and 4, both modes; poses rebuilt from the kept errors), alternated: 26.7 ms a bone (median) before,
#: 13.1 with the weights solved afresh, 10.8 with them kept from an earlier run (the calibration's
#: deltas were about half of the time before); with its median by partition (:func:`_median`, 7b679ee)
#: 110.9 against 49.2 ms on the same machine heavily loaded (paired ratio 2.26, 1.97 without it).
SHARED = True
#: A table keeps each frame's residual by the neighbours its fit goes through (and, at a trial's end, the
#: scale it is calibrated to): the rules judge a frame again after each frame flagged near it, mostly
#: with the same neighbours (on 20 tracks of 100 frames with noise and 4 frames turned, a fifth of
#: :meth:`_Table.residual`'s 105 calls a bone), and the frame offsets of each frame's window are kept
#: from the table's making (exact: the same arithmetic on the same numbers, the residuals to the bit; False:
#: as before). :mod:`core.studies.tracking.loop_host` times it.
MEMO = True
#: A table makes its poses' deltas (every frame offset's, and a trial's end frames') in one batch each,
#: not one per offset and end frame, and the pair rule (:mod:`core.tracking.flags_pairs`) finds its pairs
#: and the pairs it scores for all frames at once (exact: each row's arithmetic is the same in any batch,
#: the same booleans; False: as before).
BATCHED = True
#: ``(degree, offsets' bytes)`` -> :meth:`_Table._weights`' value, for every table (:data:`SHARED`);
#: emptied when it holds :data:`_WEIGHTS_MAX`.
_WEIGHTS: dict = {}
_WEIGHTS_MAX = 4096
#: A trial's end frame's residual is calibrated by the median residual of the bone's frames fitted alike
#: when this many or more can be (:meth:`_Table._factor`).
ALIKE = 8


def _deltas(A: np.ndarray, B: np.ndarray, c: np.ndarray) -> np.ndarray:
    """``(n, 6)`` :func:`~core.tracking.checks.pose_delta` of rigid poses ``A[k]`` to ``B[k]`` about
    ``c`` (mm, rotation vector in rad), batched; the rotations between neighbouring frames are far from
    a half turn."""
    Ra, Rb = A[:, :3, :3], B[:, :3, :3]
    R = Rb @ np.swapaxes(Ra, 1, 2)
    w = np.stack([R[:, 2, 1] - R[:, 1, 2], R[:, 0, 2] - R[:, 2, 0], R[:, 1, 0] - R[:, 0, 1]], axis=1)
    sn = 0.5 * np.linalg.norm(w, axis=1)
    cs = 0.5 * (np.trace(R, axis1=1, axis2=2) - 1.0)
    th = np.arctan2(sn, cs)
    k = np.where(sn < 1e-12, 0.5, th / (2.0 * np.maximum(sn, 1e-300)))
    disp = Rb @ c + B[:, :3, 3] - Ra @ c - A[:, :3, 3]
    return np.concatenate((disp, k[:, None] * w), axis=1)


def _median(S: np.ndarray) -> np.ndarray:
    """``np.median(S, axis=0)`` to the bit (the middle order statistics' mean as numpy takes it), without
    its overhead, for finite ``S`` (``(m, k)``, m >= 1); numpy's own otherwise."""
    m = len(S)
    if not np.isfinite(S).all():
        return np.median(S, axis=0)
    k = m // 2
    if m % 2:
        return np.partition(S, k, axis=0)[k] / 1.0
    part = np.partition(S, [k - 1, k], axis=0)
    return (part[k - 1] + part[k]) / 2.0


class _Table:
    """The poses' parameters about each frame of its neighbours within ``half_window`` (frames sorted
    by number), and each frame's normalised residual given the frames in use (module docs)."""

    def __init__(self, fr: np.ndarray, P: np.ndarray, ok: np.ndarray, c: np.ndarray, half_window: int,
                 degree: int, ends: bool = False) -> None:
        n, h = len(fr), int(half_window)
        self.fr, self.ok, self.degree, self.P, self.c = fr, ok, int(degree), P, c
        # every k-th frame tracked: the window counts tracked frames (k the frames' median spacing)
        self.step = max(1, int(np.median(np.diff(fr)))) if n > 1 else 1
        self.offsets = np.array([d for d in range(-h, h + 1) if d != 0], dtype=int)
        self.Y = np.full((n, len(self.offsets), 6), np.nan)
        self.near = np.zeros((n, len(self.offsets)), dtype=bool)
        idx = np.arange(n)
        pairs = []
        for m, d in enumerate(self.offsets):  # distinct frame numbers: neighbours lie within h places
            j = idx + d
            inside = (j >= 0) & (j < n)
            a, b = idx[inside], j[inside]
            good = ok[a] & ok[b] & (np.abs(fr[b] - fr[a]) <= h * self.step)
            a, b = a[good], b[good]
            if len(a):
                if BATCHED:
                    pairs.append((a, b, m))
                else:
                    self.Y[a, m] = _deltas(P[a], P[b], c)
                self.near[a, m] = True
        if pairs:  # (BATCHED) every offset's deltas in one batch: each row's arithmetic as alone
            A = np.concatenate([a for a, _, _ in pairs])
            D = _deltas(P[A], P[np.concatenate([b for _, b, _ in pairs])], c)
            self.Y[A, np.concatenate([np.full(len(a), m) for a, _, m in pairs])] = D
        self._solve: dict = {}
        self._memo: dict = {}  # (frame index, neighbours' mask bytes[, scale bytes]) -> residual (MEMO)
        # each frame's window: its neighbours' indices (clipped) and frame offsets, as _fit computes them
        jc = np.clip(idx[:, None] + self.offsets, 0, max(n - 1, 0))
        self._jc, self._dx = jc, (fr[jc] - fr[:, None]).astype(float)
        # a trial's end: a frame whose ±h window reaches past the first or last frame with a pose is
        # fitted through the frames of the 2h-wide window shifted inside the trial (module docs)
        self.span = 2 * h
        self.scale: np.ndarray | None = None  # the bone's median residual (mm, deg): calibrate()
        self._alike: dict = {}
        self._offsets: tuple | None = None
        self._okH: tuple | None = None  # (frames with a pose, their rows of _offset_deltas' H) (MEMO)
        self.ext: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        self.end = np.zeros(n, dtype=bool)
        self.ends = bool(ends)
        if self.ends and ok.any():
            lo, hi = int(fr[ok].min()), int(fr[ok].max())
            w, span = h * self.step, 2 * h * self.step
            todo = []
            for i in np.flatnonzero(ok & ((fr - w < lo) | (fr + w > hi))):
                a = min(max(int(fr[i]) - w, lo), max(lo, hi - span))
                js = np.arange(max(0, i - 2 * h), min(n, i + 2 * h + 1))
                js = js[(js != i) & ok[js] & (fr[js] >= a) & (fr[js] <= a + span)]
                self.end[i] = True
                if BATCHED:
                    todo.append((int(i), js))
                else:
                    self.ext[int(i)] = (js, _deltas(np.repeat(P[i:i + 1], len(js), axis=0), P[js], c))
            if todo:  # (BATCHED) the end frames' deltas in one batch
                D = _deltas(P[np.concatenate([np.full(len(js), i) for i, js in todo])],
                            P[np.concatenate([js for _, js in todo])], c)
                at = np.cumsum([0] + [len(js) for _, js in todo])
                for k, (i, js) in enumerate(todo):
                    self.ext[i] = (js, D[at[k]:at[k + 1]])

    def residuals(self, use: np.ndarray) -> np.ndarray:
        """``(n, 2)`` :meth:`residual` of every frame in ``use``, frames with the same neighbours'
        offsets batched (most have all of them)."""
        n = len(use)
        j = np.arange(n)[:, None] + self.offsets
        sel = self.near & use[np.clip(j, 0, n - 1)]
        out = np.full((n, 2), np.nan)
        todo = np.flatnonzero(use)
        steps = self.fr[np.clip(j[todo], 0, n - 1)] - self.fr[todo, None]
        full = todo[sel[todo].all(axis=1) & (steps == self.offsets * self.step).all(axis=1)  # evenly spaced
                    & ~self.end[todo]]
        if len(full):
            hit = self._weights((self.offsets * self.step).astype(float))
            if hit is not None:
                row, k = hit
                r = np.einsum("m,nmk->nk", row, self.Y[full])
                out[full, 0] = np.linalg.norm(r[:, :3], axis=1) / k
                out[full, 1] = np.degrees(np.linalg.norm(r[:, 3:], axis=1)) / k
        for i in np.setdiff1d(todo, full):
            out[i] = self.residual(int(i), use)
        return out

    def calibrate(self, scale: np.ndarray) -> None:
        """The bone's median residual (mm, degrees; the check's scale) that a trial's end frames'
        residuals are calibrated to (:meth:`_factor`)."""
        self.scale = np.asarray(scale, dtype=float)
        self._scale_key = self.scale.tobytes()  # (residual's key at a trial's end, MEMO)

    def _factor(self, x: np.ndarray, row: np.ndarray, k: float) -> np.ndarray:
        """How much wider than the bone's median (:meth:`calibrate`; 1 where none, or narrower) the
        median residual of the bone's frames fitted alike is — each through the frames at the same frame
        offsets ``x`` from it, or the mirrored ones (the fit's weights ``row``, ``sqrt(1 + leverage)``
        ``k``), the larger of mm and degrees: an extrapolation follows the motion's acceleration less well
        than a fit on both sides (module docs of :mod:`core.tracking.flags_ends`)."""
        if self.scale is None:
            return 1.0
        key = x.tobytes()
        if key not in self._alike:
            off = x.astype(int)
            if SHARED and np.abs(off).max() <= self.span * self.step:  # within a trial's end window
                S = self._alike_shared(off, row, k)
            else:
                S = self._alike_residuals(off, row, k)
            f = 1.0
            if len(S) >= ALIKE:
                med = _median(S) if SHARED else np.median(S, axis=0)
                f = max(1.0, float((med / np.maximum(self.scale, 1e-12)).max()))
            self._alike[key] = f
        return self._alike[key]

    def _alike_residuals(self, off: np.ndarray, row: np.ndarray, k: float) -> np.ndarray:
        """``(m, 2)`` residuals (mm, degrees) of the bone's frames fitted through the frames at offsets
        ``off`` from them, then at ``-off`` (:meth:`_factor`), the deltas computed for these offsets."""
        fr, ok = self.fr, self.ok
        js = np.flatnonzero(ok)
        vals = [np.zeros((0, 2))]
        for sign in (1, -1):
            want = fr[js, None] + sign * off
            idx = np.minimum(np.searchsorted(fr, want), len(fr) - 1)
            good = ((fr[idx] == want) & ok[idx]).all(axis=1)
            a, b = js[good], idx[good]
            if len(a):
                Y = _deltas(np.repeat(self.P[a], len(off), axis=0), self.P[b.ravel()],
                            self.c).reshape(len(a), len(off), 6)
                r = np.einsum("m,nmk->nk", row, Y) / k
                vals.append(np.stack([np.linalg.norm(r[:, :3], axis=1),
                                      np.degrees(np.linalg.norm(r[:, 3:], axis=1))], axis=1))
        return np.concatenate(vals)

    def _alike_shared(self, off: np.ndarray, row: np.ndarray, k: float) -> np.ndarray:
        """:meth:`_alike_residuals` (the same values to the bit, both offsets' signs in one batch) from
        every offset's deltas computed once (:meth:`_offset_deltas`, :data:`SHARED`)."""
        H, D, at = self._offset_deltas()
        if MEMO:  # (the frames with a pose and their rows of H kept)
            if self._okH is None:
                self._okH = (np.flatnonzero(self.ok), H[self.ok])
            js, Hj = self._okH
        else:
            js = np.flatnonzero(self.ok)
            Hj = H[js]
        cols = np.stack([at[off], at[-off]])  # (2, m): the offsets, then mirrored
        a = [js[Hj[:, c].all(axis=1)] for c in cols]
        rows = np.concatenate(a)
        if not len(rows):
            return np.zeros((0, 2))
        C = np.repeat(cols, [len(a[0]), len(a[1])], axis=0)
        r = np.einsum("m,nmk->nk", row, D[rows[:, None], C]) / k
        if MEMO:  # np.linalg.norm's arithmetic (the square root of add.reduce of x * x: for three terms
            # (a + b) + c, 200 000 random rows the same to the bit), written in place
            out = np.empty((len(r), 2))
            q = r * r
            np.sqrt(q[:, 0] + q[:, 1] + q[:, 2], out=out[:, 0])
            np.degrees(np.sqrt(q[:, 3] + q[:, 4] + q[:, 5]), out=out[:, 1])
            return out
        return np.stack([np.linalg.norm(r[:, :3], axis=1), np.degrees(np.linalg.norm(r[:, 3:], axis=1))],
                        axis=1)

    def _offset_deltas(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(H, D, at)`` for every frame offset ``d`` within ``2 * half_window`` tracked frames
        (:data:`SHARED`), column ``at[d]``: which frames with a pose have one ``d`` frame numbers
        on (``H``, ``(n, K)`` bool) and the :func:`_deltas` from each such frame's pose to that one's
        (``D``, ``(n, K, 6)``, NaN elsewhere); computed once, in one batch."""
        if self._offsets is None:
            fr, ok = self.fr, self.ok
            m = self.span * self.step
            ds = np.r_[np.arange(-m, 0), np.arange(1, m + 1)]
            at = np.full(2 * m + 1, -1, dtype=int)
            at[ds + m] = np.arange(len(ds))
            at = np.roll(at, -m)  # at[d] for d in -m..m (negative d from the end)
            js = np.flatnonzero(ok)
            want = fr[js, None] + ds
            idx = np.minimum(np.searchsorted(fr, want), len(fr) - 1)
            good = (fr[idx] == want) & ok[idx]
            H = np.zeros((len(fr), len(ds)), dtype=bool)
            D = np.full((len(fr), len(ds), 6), np.nan)
            H[js] = good
            a, k = np.nonzero(good)
            if len(a):
                D[js[a], k] = _deltas(self.P[js[a]], self.P[idx[a, k]], self.c)
            self._offsets = (H, D, at)
        return self._offsets

    def cut_residuals(self, use: np.ndarray) -> np.ndarray:
        """:meth:`residuals` with every frame fitted through its ±``half_window`` window cut at the
        trial's ends, as before :mod:`core.tracking.flags_ends`."""
        ext, end = self.ext, self.end
        self.ext, self.end = {}, np.zeros_like(end)
        try:
            return self.residuals(use)
        finally:
            self.ext, self.end = ext, end

    def _weights(self, x: np.ndarray):
        """The fit's value at the frame as weights on neighbours at offsets ``x``, and
        ``sqrt(1 + leverage)``; None when the fit is singular."""
        key = x.tobytes()
        if key not in self._solve:
            if SHARED and (self.degree, key) in _WEIGHTS:
                self._solve[key] = _WEIGHTS[(self.degree, key)]
                return self._solve[key]
            A = np.vander(x, self.degree + 1)
            AtA = A.T @ A
            if abs(np.linalg.det(AtA)) < 1e-12:
                self._solve[key] = None
            else:
                self._solve[key] = (np.linalg.solve(AtA, A.T)[-1],
                                    math.sqrt(1.0 + float(np.linalg.inv(AtA)[-1, -1])))
            if SHARED:
                if len(_WEIGHTS) >= _WEIGHTS_MAX:
                    _WEIGHTS.clear()
                _WEIGHTS[(self.degree, key)] = self._solve[key]
        return self._solve[key]

    def _fit(self, i: int, use: np.ndarray, sel: np.ndarray | None = None):
        """The fit's weights on frame ``i``'s neighbours in ``use``, ``sqrt(1 + leverage)`` and which
        neighbours (a mask of :attr:`offsets`, or at a trial's end of its window's frames, :attr:`ext`);
        None with fewer than ``degree + 2`` or a singular fit. ``sel``: that mask, where the caller has it
        (:meth:`residual`)."""
        if i in self.ext:
            js, _ = self.ext[i]
            sel = use[js] if sel is None else sel
            if sel.sum() < self.degree + 2:
                return None
            x = (self.fr[js[sel]] - self.fr[i]).astype(float)
            hit = self._weights(x)
            return None if hit is None else (hit[0], hit[1] * self._factor(x, *hit), sel)
        if MEMO:  # (the same numbers: a neighbour in near[i] lies inside the table, its index unclipped)
            sel = self.near[i] & use[self._jc[i]] if sel is None else sel
            if sel.sum() < self.degree + 2:
                return None
            hit = self._weights(self._dx[i][sel])
            return None if hit is None else (*hit, sel)
        j = i + self.offsets
        sel = self.near[i] & use[np.minimum(np.maximum(j, 0), len(use) - 1)]
        if sel.sum() < self.degree + 2:
            return None
        hit = self._weights((self.fr[j[sel]] - self.fr[i]).astype(float))
        return None if hit is None else (*hit, sel)

    def residual(self, i: int, use: np.ndarray) -> tuple[float, float]:
        """Frame ``i``'s normalised residual (mm, degrees) against the fit through its neighbours in
        ``use`` (NaN with fewer than ``degree + 2``); kept by those neighbours (:data:`MEMO`)."""
        if not MEMO:
            return self._residual(i, use)
        ext = self.ext.get(i)
        if ext is not None:
            sel = use[ext[0]]
            key = (i, sel.tobytes(), None if self.scale is None else self._scale_key)
        else:
            sel = self.near[i] & use[self._jc[i]]
            key = (i, sel.tobytes())
        hit = self._memo.get(key)
        if hit is None:
            hit = self._memo[key] = self._residual(i, use, sel)
        return hit

    def _residual(self, i: int, use: np.ndarray, sel: np.ndarray | None = None) -> tuple[float, float]:
        """:meth:`residual` computed (``sel``: :meth:`_fit`'s)."""
        hit = self._fit(i, use, sel)
        if hit is None:
            return math.nan, math.nan
        row, k, sel = hit
        r = row @ self._y(i)[sel]
        return math.sqrt(float(r[:3] @ r[:3])) / k, math.degrees(math.sqrt(float(r[3:] @ r[3:]))) / k

    def residual_vector(self, i: int, use: np.ndarray) -> np.ndarray | None:
        """Frame ``i``'s residual as a vector (``(6,)``: mm, rotation vector in rad; the fit's value at
        ``i`` in the parameters about ``i``'s own pose, divided by ``sqrt(1 + leverage)``: its norms are
        :meth:`residual`'s); None where :meth:`residual` is NaN."""
        hit = self._fit(i, use)
        if hit is None:
            return None
        row, k, sel = hit
        return (row @ self._y(i)[sel]) / k

    def _y(self, i: int) -> np.ndarray:
        """Frame ``i``'s neighbours' parameters about it, in :meth:`_fit`'s order."""
        return self.ext[i][1] if i in self.ext else self.Y[i]

    def neighbours(self, i: int, use: np.ndarray) -> np.ndarray:
        """The indices of frame ``i``'s neighbours in ``use`` that its fit goes through."""
        if i in self.ext:
            js = self.ext[i][0]
            return js[use[js]]
        j = i + self.offsets
        return j[self.near[i] & use[np.clip(j, 0, len(use) - 1)]]
