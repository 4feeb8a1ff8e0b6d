"""Where a bone's bias in the harder trial comes from (:mod:`core.studies.tracking.hard_trial`,
``--ablation BONE``; :func:`ablate_bias`).

The bone registered from its true pose with one cause removed at a time. Seed 2's tibia, 0.13–0.14
mm off in every frame with either GC form on one H100 (8× its bound, ``tracking_hard_gpu.json``),
is as far off on this 2-core CPU at 384² / 0.5 mm (x +0.143, y −0.066 mm,
``resources/benchmarks/tracking_hard_bias_cpu.json``). It is not the search's doing: the cost's
optimum is moved by two things the model lacks. In view 0 the tibia's shaft runs out of the image
(to 1.43× the distortion's scale, past the round field), so what the cost sees of it lies where the
3 % residual distortion is largest (the exact inverse: x +0.089 mm), and the untracked fibula
covers 14 % of its projection there (without the fibula: x +0.066; without both: x +0.011, y
+0.011). The CT's PSF and noise change nothing (the truth's volume gives the same x, y bias); the
part along the shaft (z) shrinks with the truth's volume (seed 2 −0.038 → −0.004 mm, seed 0 −0.068
→ −0.039), and not through the shaft's cut end: with the CT's top slice set to air (the CT's cut
0.55 voxel below the truth's instead of 0.45 above) z moved by 0.01 mm only (−0.030, −0.054). Seeds
0 and 1 (more fibula overlap, other distortions) are 0.09 and 0.06 mm off.
"""

from __future__ import annotations

import numpy as np

from core.studies.tracking.acceptance import pose_errors

__all__ = ["ABLATIONS", "ablate_bias"]

ABLATIONS = ("as_is", "exact_distortion", "no_fibula", "exact_distortion_no_fibula", "truth_volume",
             "ct_top_slice_air")


def ablate_bias(hr, *, seed: int, pixels: int, spacing: float, frames=(0, 4), bone: str = "tibia",
                device: str | None = None, variants=ABLATIONS) -> dict:
    """Where a bone's bias comes from, on the trial ``hr`` (a
    :class:`~core.studies.tracking.hard_trial.HardRun` of ``seed``, ``pixels``, ``spacing``;
    :func:`core.studies.tracking.hard_trial.bias_ablation` builds it): ``bone`` registered from its true
    pose (``search="newton"``, the default GC) in ``frames`` of the trial (``as_is``), of frames
    corrected with the exact distortion inverse instead of the 3 % wrong one (``exact_distortion``), of
    frames without the untracked fibula (``no_fibula``), both, and with the truth's volume in place of
    the CT (``truth_volume``: the CT's PSF, resampling and noise), and with the CT's top slice set to air
    (``ct_top_slice_air``: a bone the volume cuts ends 0.55 voxel below the truth's cut instead of 0.45
    above it, :func:`core.synthetic.hard_foot.ct_of`'s offset). Errors are :func:`pose_errors` (mm,
    degrees); per view also the bone's projected extent (pixels, and its largest radius over the
    distortion's scale: beyond 1 it leaves the round field) and its overlap with the fibula."""
    from core.render import DRRRenderer
    from core.tracking.bones import bone_model
    from core.tracking.cost import prepare_frame
    from core.tracking.register import register
    from core.tracking.trial import TrackingOptions

    b = hr.names.index(bone)
    fib = hr.scene.names.index("fibula")
    reg = TrackingOptions().registration
    from dataclasses import replace

    reg = replace(reg, search="newton")
    parts = hr.scene.renderer(device=device)
    exact = [im.distortion for im in hr.scene.imaging]

    def image(f, corrections, drop_fibula):
        L = hr.line_integrals(f)
        if drop_fibula:
            L = L - parts._bones.render(hr.scene.poses(f)[None], roi="full").numpy()[0][:, fib]
        return [c.unwarp(m.to_float(m.apply(L[v], rng=hr.scene.frame_rng(f, v))))
                for v, (m, c) in enumerate(zip(hr.scene.imaging, corrections, strict=True))]

    geometry = []
    P0 = parts._bones.render(hr.scene.poses(frames[0])[None], roi="full").numpy()[0]
    m0 = hr.models[b]
    k, j, i = np.nonzero(m0.mask)
    pts = m0.volume.index_to_physical(np.column_stack([i, j, k])[::50].astype(float))
    T0 = hr.truth(frames[0])[b]
    for v, cam in enumerate(hr.scene.rig):
        uv = cam.project(pts @ T0[:3, :3].T + T0[:3, 3])
        d = hr.scene.imaging[v].distortion
        r = np.hypot(uv[:, 0] - d.center[0], uv[:, 1] - d.center[1]) / d.scale_px
        own, other = P0[v, hr.scene.names.index(bone)] > 0.05, P0[v, fib] > 0.05
        geometry.append({"u_px": [float(uv[:, 0].min()), float(uv[:, 0].max())],
                         "v_px": [float(uv[:, 1].min()), float(uv[:, 1].max())], "size_px": cam.width,
                         "max_radius_over_scale": float(r.max()), "projected_px": int(own.sum()),
                         "fibula_overlap_px": int((own & other).sum())})
    out = {"seed": seed, "bone": bone, "pixels": pixels, "voxel_mm": spacing, "frames": list(frames),
           "views": geometry, "variants": {}}
    for name in variants:
        model, renderer = hr.models[b], hr.renderer
        if name in ("truth_volume", "ct_top_slice_air"):
            if name == "truth_volume":
                vol = hr.trial.truth_volumes[b]
            else:
                from dataclasses import replace as _replace

                data = np.array(hr.trial.ct[b].data)
                data[-1] = -1000
                vol = _replace(hr.trial.ct[b], data=data)
            model = bone_model(vol, name=bone, mesh=False)
            vols = [mm.volume.to_attenuation(hr.transfer) for mm in hr.models]
            vols[b] = model.volume.to_attenuation(hr.transfer)
            renderer = DRRRenderer(hr.scene.rig, vols, device=device)
        E = []
        for f in frames:
            imgs = image(f, exact if "exact" in name else hr.corrections, "no_fibula" in name)
            T = hr.truth(f)[b]
            r = register(renderer, prepare_frame(imgs), bone=b, initial_pose=T, center=model.centroid,
                         options=reg, outline=model.outline)
            E.append(pose_errors(r.pose, T, model.centroid))
        E = np.array(E)
        out["variants"][name] = {"per_frame": E.round(4).tolist(),
                                 "mean_mm": E[:, :3].mean(0).round(4).tolist(),
                                 "mean_deg": E[:, 3:].mean(0).round(4).tolist(),
                                 "mean_norm_mm": float(np.linalg.norm(E[:, :3].mean(0)))}
    return out
