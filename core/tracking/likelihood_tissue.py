"""The likelihood final stage's extra regressors (:class:`core.tracking.engine_likelihood.LikelihoodEngine`'s
frame's soft tissue, :meth:`~_TissueRegressors.set_tissue`, or given images, ``set_frame(regressors=)``):
uploaded or rendered on the device, high-passed like the frame, and the moments tables they widen. A
mixin of the engine's; and the final stage's side of the tissue (:func:`tissue_renderer`, the volumes'
renderer kept per renderer, and ``_set_tissue``, the volumes rendered at the current estimate of their
bones' poses; :mod:`core.tracking.final_stage` re-exports :func:`tissue_renderer`).

The semantics are those of :class:`~core.tracking.likelihood_cost.LikelihoodCost`'s ``regressors``:
the frame's ``q`` regressors a view ``T_1 … T_q`` are appended to the moments' ``z`` (``12 + q``
entries, :func:`~core.tracking.likelihood_kernels.regressor_kernels`) and to ``A = (D, 1[, u, v], O,
T)``, each with its own coefficient fitted at every pose; without them the kernels and the numbers
are the plain ones.

The tissue regressor is only as good as the volume it is rendered from: its error in the
high-passed band moves a bone wherever it crosses the bone's edges, and it is not the poses it is
rendered at (:mod:`core.studies.tracking.tissue_tibia`: at the tracker's poses the same bias as at
the true ones, within 0.2 µm RMS at 256²; with the tissue's own pose derivative in the step worse in every
volume). Measured there (one NVIDIA H200, the acceptance trial at 1024², three bones jointly, the
stage at the 8 px high-pass, RMS over the bound mm/° tibia, talus, calcaneus): the trial's soft
tissue resampled to 4 mm 1.92/1.66, 1.17/1.18, 1.15/1.35 (the tibia worse than without it,
1.72/1.45); to 2 mm 1.54/1.36, 1.15/1.19, 1.12/1.30 (every bone better). Give the stage the tissue
at 2 mm; with a coarser volume, leave it out of the tibia's stage
(:class:`core.tracking.final_stage.BoneStage` ``tissue=False``).
"""

from __future__ import annotations

import time
import weakref
from collections.abc import Sequence

import numpy as np
import warp as wp

from .likelihood_kernels import NZ, fluence_psf_kernel, highpass_kernel, regressor_sum_kernel


class _TissueRegressors:
    """:class:`~core.tracking.engine_likelihood.LikelihoodEngine`'s extra regressors (its attributes:
    ``n_views``, ``views``, ``roi``, ``_cap``, ``_ref_hw``, buffers, launches)."""

    def _frame_regressors(self, regressors, hw) -> None:
        """``set_frame``'s ``regressors`` (per view ``(q, h, w)`` or ``(h, w)`` images of the regions
        ``hw``), or none: uploaded and high-passed like the frame."""
        nv, (Hc, Wc) = self.n_views, self._cap
        self._q, self._t = 0, None
        if regressors is not None:
            R = [np.asarray(r, np.float32).reshape(-1, *np.shape(r)[-2:]) for r in regressors]
            q = len(R[0])
            if len(R) != nv or any(len(r) != q or r.shape[1:] != tuple(hw[v]) for v, r in enumerate(R)):
                raise ValueError(f"regressors: expected per view (q, h, w) images of the regions "
                                 f"{[tuple(x) for x in hw]}, got {[r.shape for r in R]}")
            host = np.zeros((q * nv, Hc, Wc), np.float32)
            for v, r in enumerate(R):
                host[v::nv, : r.shape[1], : r.shape[2]] = r
            raw = self._buffer("t_raw", host.shape)
            raw.assign(host)
            self._filter_regressors(raw, q)

    def _filter_regressors(self, raw, q: int) -> None:
        """The frame's ``q`` regressors a view from ``raw`` (``(q · views, H, W)``, as the frame
        shows them): high-passed like the frame."""
        t = self._buffer("t", raw.shape)
        if self.highpass_px:
            low = self._blurred("t", raw, self.n_views)
            self._launch("highpass_t", highpass_kernel, raw.shape, [raw, low, 1.0, t])
        else:
            wp.copy(t, raw)
        self._t, self._q = t, int(q)

    def set_tissue(self, renderer, poses, *, volumes=None, each: bool = False, psf=None) -> None:
        """The frame's extra regressors (after :meth:`set_frame`): the DRRs of ``renderer``'s
        volumes ``volumes`` (default all; e.g. soft-tissue parts; the same cameras as the engine's
        renderer) at ``poses (n, 4, 4)`` in this frame's regions, rendered on the device, as the
        frame shows them — their line integrals summed (or, ``each``, each volume its own
        regressor) and, with ``psf`` (an odd 2-D kernel estimated from calibration images), blurred
        as fluence, ``-log(psf ∗ exp(-L))`` — then high-passed like the frame (set_frame's
        ``regressors``); each with its own coefficient fitted at every pose. Nothing is read
        back."""
        t0 = time.perf_counter()
        P = np.asarray(poses, dtype=float).reshape(-1, 4, 4)
        n, nv, (Hc, Wc) = len(P), self.n_views, self._cap
        vols = list(range(n)) if volumes is None else [int(k) for k in volumes]
        batch = renderer.render(P[None], views=self.views, bones=vols,
                                roi=self.roi[None, :, None, :].repeat(n, axis=2))
        q = n if each else 1
        raw = self._buffer("t_raw", (q * nv, Hc, Wc))
        wp.launch(regressor_sum_kernel, dim=(nv, Hc, Wc), device=self.device,
                  inputs=[batch.images, n, self._ref_hw, int(each), raw])
        if psf is not None:
            k = np.asarray(psf, dtype=np.float64)
            if k.ndim != 2 or k.shape[0] % 2 == 0 or k.shape[1] % 2 == 0 or k.sum() <= 0:
                raise ValueError(f"psf: expected an odd-sized 2-D kernel with a positive sum, got {k.shape}")
            key = ("t_psf_taps", k.tobytes(), k.shape)
            taps = self._bufs.get(key)
            if taps is None:
                taps = self._bufs[key] = wp.array((k / k.sum()).astype(np.float32), dtype=wp.float32,
                                                  device=self.device)
            out = self._buffer("t_psf", raw.shape)
            wp.launch(fluence_psf_kernel, dim=raw.shape, inputs=[raw, out, taps, self._ref_hw, nv],
                      device=self.device)
            raw = out
        self._filter_regressors(raw, q)
        self.timer.host += time.perf_counter() - t0

    def _tables_q(self) -> tuple:
        """The moments table on the device and its pinned host copy for this frame's regressors."""
        if not self._q:
            return self._acc, self._host_acc
        nz = NZ + self._q
        acc = self._buffer(("acc", self._q), (self.n_views, nz * nz), wp.float64)
        host = self._pinned(("acc", self._q), (self.n_views, nz * nz), wp.float64, exact=True)
        return acc, host


_TISSUE_RENDERERS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def tissue_renderer(renderer, tissue: Sequence) -> object:
    """A :class:`~core.render.DRRRenderer` of the volumes of ``tissue`` (``(CTVolume, bone)``
    pairs; volumes in HU through the default transfer) with ``renderer``'s cameras and device,
    kept for ``renderer``'s lifetime."""
    from ..render import DRRRenderer

    per = _TISSUE_RENDERERS.setdefault(renderer, {})
    key = tuple(id(v) for v, _ in tissue)
    hit = per.get(key)
    if hit is None:
        vols = [v if v.units != "HU" else v.to_attenuation() for v, _ in tissue]
        hit = per[key] = (DRRRenderer(renderer.cameras, vols, device=str(renderer.device)),
                          tuple(v for v, _ in tissue))  # (the volumes kept: their ids are the key)
    return hit[0]


def _set_tissue(eng, renderer, model, bone: int, pose, others):
    """The engine's tissue regressor of this frame (``model``'s tissue, the stage's
    :class:`~core.tracking.likelihood_model.FinalModel`): each volume at the
    current estimate of its bone's pose — the stage's own bone at the similarity's pose ``pose``,
    a neighbour at its pose in ``others`` — those of bones with neither left out. Returns the
    callable that renders it again at the first refinement's ``x`` (``tissue_again`` and a volume
    following the stage's bone), else None."""
    if not model.tissue:
        return None
    known = {int(bone): np.asarray(pose, dtype=float)}
    if others is not None:
        for P, b in zip(np.asarray(others[0], dtype=float).reshape(-1, 4, 4), others[1], strict=True):
            known.setdefault(int(b), P)
    use = [k for k, (_, b) in enumerate(model.tissue) if b in known]
    if not use:
        return None
    tr = tissue_renderer(renderer, model.tissue)
    follows = [model.tissue[k][1] for k in use]

    def render(x=None) -> None:
        own = known[int(bone)] if x is None else eng.poses(np.asarray(x, dtype=float)[None])[0]
        P = np.stack([own if b == int(bone) else known[b] for b in follows])
        eng.set_tissue(tr, P, volumes=use, each=model.tissue_each, psf=model.tissue_psf)

    render()
    return render if model.tissue_again and int(bone) in follows else None
