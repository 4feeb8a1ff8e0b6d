"""The tracking trial's distortion correction estimated from distortion-grid frames, as a
calibration session does it (``python -m core.studies.tracking.grid_correction``).

The acceptance trial (:class:`core.studies.tracking.acceptance.TrackingScene`) undoes each view's
distortion with the true model with ``k1`` and the twist 3 % off (``correction="model"``). A user's
correction comes from the calibration session instead: here each view of the trial gets the
frames a session records (:func:`grid_session`: dark frames, empty-field frames and frames of
the hole grid on the intensifier at one hand-placed position, with the walkway plate in the beam,
each through the *same* view's imaging chain: distortion, quantum noise, blur, glare, roll-off,
camera) and the session's own steps estimate the correction
(:func:`core.calibration.session.prepare`, :func:`~core.calibration.session.flatfield_step`,
:func:`~core.calibration.session.distortion_step`: flatfield from the dark and empty-field
frames, every grid frame detected and indexed, the frames of the placement averaged, the ideal
grid refined, the model chosen by cross-validation among
:data:`core.imaging.distortion_eval.AUTO_MODELS`). The numbers of frames are the synthetic
session's defaults (:func:`core.synthetic.write_calibration_session`: 5 grid, 5 dark and 10
empty-field frames per camera). No truth enters the estimate.

The fitted model's ideal frame is the corrected image's own (the grid's lattice fixes it only up
to a similarity: shift, scale, turn); a lab's rig calibration is done in that frame, so the
trial, whose cameras are the true ones, stands for a perfect rig calibration by mapping the true
pinhole frame onto the fit's with the least-squares similarity over the round field
(:class:`GridCorrection` ``align``; its size is reported). That similarity is the only thing
taken from the truth, in the place of the bundle adjustment.

Measured (:func:`run`): per view the residual distortion of the grid correction and of the 3 %
model over the round field (points every 8 px within 0.95 of the distortion's radius, as
:meth:`TrackingScene.residual_distortion_mm`), RMS and maximum in mm at the rig's centre and in
pixels, both as they are and with the best similarity taken out (``similarity_removed``), the RMS
in five rings of the radius, per bone the RMS over the pixels its image covers in the trial
(frames 0, 10, …, 90: the tibia reaches the rim, the talus stays within a third of the radius),
and the grid correction without the alignment too (``unaligned``), for 1 and 5 grid frames; the
chosen models and their cross-validation tables. JSON on stdout
(and ``--out``).

Measured at 1024² on this 2-core CPU machine (``resources/benchmarks/tracking_grid_correction_cpu.json``):
the grid correction of the session's 5 frames leaves 0.014 mm RMS over the field (0.021 mm
without the alignment; 1 frame 0.016, 10 frames 0.012) against the 3 % model's 0.058 mm; over
the bones' images tibia 0.0075 / talus 0.0056 / calcaneus 0.0068 mm against 0.032 / 0.0027 /
0.025 mm (the 3 % model's error grows as r³ towards the rim, where the tibia reaches); its maximum,
at the rim of one view, is 0.14 mm against 0.13 mm. The trial tracked with it on one NVIDIA H200
(``resources/benchmarks/tracking_grid_correction_h200.json``, three bones jointly): final stage
tibia 1.50 / 1.42×, talus 1.38 / 1.31×, calcaneus 1.20 / 1.36× its bound (mm / degrees), against
2.16 / 1.46, 1.38 / 1.31, 1.90 / 1.40 with the 3 % model; no frame over 4× its bound. Each bone
tracked alone with the stage (``ml_cost --final --correction grid --cases talus,tibia,calcaneus``,
``resources/benchmarks/tracking_grid_stage_modes_h200.json``, one NVIDIA H200): tibia 1.48 / 1.53×,
talus 1.50 / 1.50×, calcaneus 1.19 / 1.33×, no frame over 4× (the tracker alone: 11, 9 and 1 frames
over 4×, all silent); the same call repeated the joint numbers above. The acceptance study undoes
its frames' distortion with this correction by default
(:data:`core.studies.tracking.acceptance.DEFAULT_CORRECTION`). The exact correction (the true
model, ``TrackingScene(correction="exact")``, a study-only oracle) on the same raw frames gives the
stage's tibia 1.47 / 1.54× alone and 1.51 / 1.37× jointly against this correction's 1.48 / 1.53 and
1.50 / 1.42 (``ml_cost --final --correction grid,exact``,
``resources/benchmarks/tracking_exact_correction_h200.json``, one NVIDIA H200): the leftover
distortion is not what holds the tibia at ~1.5× its bound.
"""

from __future__ import annotations

import platform
import time
from dataclasses import dataclass
from itertools import pairwise

import numpy as np

from core.studies.tracking import _study_cli as cli

__all__ = ["GridCorrection", "bone_points", "bone_residuals", "estimate_corrections", "field_points",
           "grid_corrections", "grid_session", "main", "model_corrections", "residuals", "run"]

#: The acceptance trial's bones (:data:`core.studies.tracking.acceptance.BONES` is this tuple).
TRIAL_BONES = ("tibia", "talus", "calcaneus")

#: Frames per camera of the synthetic calibration session (write_calibration_session's defaults).
SESSION_FRAMES = {"grid": 5, "dark": 5, "flat": 10}
_KV = 70.0
_TAGS = {"dark": 1, "flat": 2, "grid": 3}


@dataclass(frozen=True, eq=False)
class GridCorrection:
    """A view's distortion correction fitted from grid frames (``fit``: the session's
    :class:`core.calibration._session_grid.GridFit`), composed with the similarity ``align`` from
    the pixel frame the correction puts images in to the fit's ideal frame (``ideal = a * p + b``
    in complex notation; ``(1, 0)``: none). The same
    methods as :class:`core.synthetic.Distortion`: ``forward`` (ideal → raw), ``inverse`` and
    ``unwarp`` (a raw image resampled onto the ideal grid, linear interpolation, border replicated,
    as the trial's model correction)."""

    fit: object
    align: tuple[complex, complex] = (1.0 + 0j, 0j)
    centre: tuple[float, float] = (0.0, 0.0)  # where the summary measures the alignment's shift

    @property
    def model(self):
        return self.fit.model

    def _to_fit(self, uv) -> np.ndarray:
        a, b = self.align
        p = np.asarray(uv, float)
        z = a * (p[..., 0] + 1j * p[..., 1]) + b
        return np.stack([z.real, z.imag], axis=-1)

    def forward(self, uv) -> np.ndarray:
        p = self._to_fit(uv)
        return self.model.forward(p.reshape(-1, 2)).reshape(p.shape)

    def inverse(self, uv) -> np.ndarray:
        q = np.asarray(uv, float)
        p = self.model.inverse(q.reshape(-1, 2)).reshape(q.shape)
        a, b = self.align
        z = ((p[..., 0] + 1j * p[..., 1]) - b) / a
        return np.stack([z.real, z.imag], axis=-1)

    def tables(self, shape, step: int = 4) -> tuple[np.ndarray, np.ndarray]:
        """``cv2.remap`` tables of :meth:`forward` for an image of ``shape`` (evaluated every ``step``
        pixels, bicubic in between, as :func:`core.imaging.distortion_maps.remap_tables`); cached."""
        from scipy.interpolate import RectBivariateSpline

        h, w = (int(s) for s in shape)
        cache = self.__dict__.setdefault("_tables", {})
        if (h, w) not in cache:
            cu = np.arange(0, w - 1 + step, step, dtype=float)
            cv = np.arange(0, h - 1 + step, step, dtype=float)
            gv, gu = np.meshgrid(cv, cu, indexing="ij")
            src = self.forward(np.stack([gu, gv], axis=-1))
            rows, cols = np.arange(h, dtype=float), np.arange(w, dtype=float)
            mx = RectBivariateSpline(cv, cu, src[..., 0], kx=3, ky=3)(rows, cols).astype(np.float32)
            my = RectBivariateSpline(cv, cu, src[..., 1], kx=3, ky=3)(rows, cols).astype(np.float32)
            cache[(h, w)] = (mx, my)
        return cache[(h, w)]

    def unwarp(self, image) -> np.ndarray:
        import cv2

        img = np.asarray(image)
        mx, my = self.tables(img.shape[:2])
        return cv2.remap(img, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)

    def summary(self) -> dict:
        """JSON-ready: the chosen model, the cross-validation table, the fit's residuals, the grid
        points used, the frames, and the alignment's shift (px), scale (ppm) and turn (mdeg)."""
        f = self.fit
        a, b = self.align
        return {"model": f.spec.label, "n_frames": int(f.n_frames), "n_points": len(f.ideal_uv),
                "mm_per_px_grid": float(f.mm_per_px),
                "cross_validation": [{k: r[k] for k in ("model", "rms_px", "rms_mm", "chosen") if k in r}
                                     for r in f.table],
                "fit_residuals": f.residuals.to_dict(), "notes": list(f.notes),
                "align": {"shift_px": float(abs(b + (a - 1) * complex(*self.centre))),
                          "scale_ppm": float((abs(a) - 1) * 1e6),
                          "turn_mdeg": float(np.degrees(np.angle(a)) * 1e3)}}


def grid_session(scene, *, n_grid: int = SESSION_FRAMES["grid"], n_dark: int = SESSION_FRAMES["dark"],
                 n_flat: int = SESSION_FRAMES["flat"], seed: int = 0):
    """An in-memory calibration session of ``scene``'s views (module docs): per camera ``n_dark``
    dark frames, ``n_flat`` empty-field frames and ``n_grid`` frames of the hole grid at one
    hand-placed position (offset up to 7.5 mm, turn up to 2°, 2 mm off the face), the walkway in
    the beam for the grid, each frame through the view's imaging model (own noise per frame)."""
    from core.studies.calibration.memory_session import MemorySession
    from core.synthetic.analytic import slab_line_integrals
    from core.synthetic.calib_objects import distortion_grid, face_frame
    from core.synthetic.calibration import plate_line_integrals

    rig, models = tuple(scene.rig), tuple(scene.imaging)
    shape = rig[0].image_shape
    plate = distortion_grid(field_diameter_mm=shape[1] * rig[0].pixel_size)
    g_pose = np.random.default_rng([int(seed), 0x6A1D, 0])
    imgs: dict = {}
    names = tuple(f"cam{v + 1}" for v in range(len(rig)))

    def rng(group: str, i: int, v: int) -> np.random.Generator:
        return np.random.default_rng([int(seed), 0x6A1D, _TAGS[group], int(i), int(v)])

    for v, (cam, m, nm) in enumerate(zip(rig, models, names, strict=True)):
        off, ang = g_pose.uniform(-7.5, 7.5, size=2), np.radians(g_pose.uniform(-2.0, 2.0))
        T = face_frame(cam, gap_mm=2.0, thickness_mm=plate.thickness, offset_mm=off, angle_rad=ang)
        L = plate_line_integrals(cam, plate, T)
        if scene.floor is not None:
            z, t, mu = scene.floor
            L = L + slab_line_integrals(cam, (0.0, 0.0, z - t / 2), (0.0, 0.0, 1.0), t, mu)
        L = L.astype(np.float32)
        imgs[(nm, "grid")] = [m.apply(L, rng=rng("grid", i, v)) for i in range(int(n_grid))]
        imgs[(nm, "dark")] = [_dark(m, shape, rng("dark", i, v)) for i in range(int(n_dark))]
        zero = np.zeros(shape, np.float32)
        imgs[(nm, f"flat:{_KV:g}")] = [m.apply(zero, rng=rng("flat", i, v)) for i in range(int(n_flat))]
    manifest = {"cameras": list(names), "bit_depth": int(models[0].bits), "flat_kv": [_KV], "kv": _KV,
                "grid": {"pitch_mm": 15.0, "hole_diameter_mm": float(plate.hole_diameter)},
                "detector": {"pixel_size_mm": float(rig[0].pixel_size)}}
    return MemorySession(names, int(models[0].bits), tuple(shape), manifest, imgs)


def _dark(model, shape, g: np.random.Generator) -> np.ndarray:
    """A dark frame (X-rays off): the camera's dark level and read noise, quantised."""
    dn = np.full(shape, float(model.dark_dn))
    if model.read_noise_dn > 0:
        dn = dn + g.normal(0.0, model.read_noise_dn, size=shape)
    return np.clip(np.rint(dn), 0, 2**model.bits - 1).astype(np.uint16)


def estimate_corrections(session, *, model: str = "auto") -> list:
    """Per camera the :class:`~core.calibration._session_grid.GridFit` of the calibration session's
    flatfield and distortion steps (what ``talus calibrate`` computes before the beads)."""
    from core.calibration.session import distortion_step, flatfield_step, prepare

    setup = prepare(session)
    dist = distortion_step(setup, flatfield_step(setup), model=model)
    return [c.grid for c in dist.cameras]


def field_points(cam, distortion, step: int = 8) -> np.ndarray:
    """``(n, 2)`` ideal pixels every ``step`` px within 0.95 of the distortion's radius (the field
    of :meth:`TrackingScene.residual_distortion_mm`)."""
    v, u = np.mgrid[0:cam.height:step, 0:cam.width:step]
    uv = np.stack([u.ravel(), v.ravel()], axis=1).astype(float)
    r = np.hypot(uv[:, 0] - distortion.center[0], uv[:, 1] - distortion.center[1])
    return uv[r < 0.95 * distortion.scale_px]


def _similarity(src: np.ndarray, dst: np.ndarray) -> tuple[complex, complex]:
    """Least-squares ``dst ≈ a src + b`` (complex notation)."""
    w = src[:, 0] + 1j * src[:, 1]
    z = dst[:, 0] + 1j * dst[:, 1]
    a, b = np.linalg.lstsq(np.column_stack([w, np.ones_like(w)]), z, rcond=None)[0]
    return complex(a), complex(b)


def grid_corrections(scene, *, n_grid: int = SESSION_FRAMES["grid"], seed: int = 0, model: str = "auto",
                     align: bool = True) -> list[GridCorrection]:
    """Per view of ``scene`` the correction estimated from its calibration session (:func:`grid_session`,
    :func:`estimate_corrections`); ``align``: composed with the similarity that maps the true
    pinhole frame best onto the fit's (the stand-in for the rig calibration, module docs)."""
    fits = estimate_corrections(grid_session(scene, n_grid=n_grid, seed=seed), model=model)
    out = []
    for cam, m, f in zip(scene.rig, scene.imaging, fits, strict=True):
        ab = (1.0 + 0j, 0j)
        if align:
            uv = field_points(cam, m.distortion)
            ab = _similarity(uv, f.model.inverse(m.distortion.forward(uv)))
        c = GridCorrection(f, ab, ((cam.width - 1) / 2, (cam.height - 1) / 2))
        c.tables(cam.image_shape)  # made once here (forked frame workers inherit them)
        out.append(c)
    return out


def residuals(scene, corrections) -> list[dict]:
    """Per view the residual distortion ``corrections[v].inverse(truth.forward(p)) - p`` over the
    field (:func:`field_points`): RMS and maximum in px and in mm at the rig's centre, as it is and
    with the least-squares similarity taken out (``*_similarity_removed``)."""
    out = []
    for cam, m, c in zip(scene.rig, scene.imaging, corrections, strict=True):
        uv = field_points(cam, m.distortion)
        back = c.inverse(m.distortion.forward(uv))
        _, depth = cam.project(np.zeros((1, 3)), return_depth=True)
        mm = float(depth[0]) / cam.fx
        a, b = _similarity(uv, back)
        z = ((back[:, 0] + 1j * back[:, 1]) - b) / a
        d = {"raw": np.linalg.norm(back - uv, axis=1),
             "similarity_removed": np.abs(z - (uv[:, 0] + 1j * uv[:, 1]))}
        row = {"mm_per_px": mm, "points": len(uv)}
        for k, e in d.items():
            row[k] = {"rms_px": float(np.sqrt(np.mean(e**2))), "max_px": float(e.max()),
                      "rms_mm": float(np.sqrt(np.mean(e**2)) * mm), "max_mm": float(e.max() * mm)}
        dc = m.distortion
        r = np.hypot(uv[:, 0] - dc.center[0], uv[:, 1] - dc.center[1]) / dc.scale_px
        row["raw_rms_mm_by_radius"] = {f"{lo:.2f}-{hi:.2f}": float(np.sqrt(np.mean(d["raw"][sel] ** 2)) * mm)
                                       for lo, hi in pairwise(np.linspace(0.0, 0.95, 6))
                                       if (sel := (r >= lo) & (r < hi)).any()}
        out.append(row)
    return out


def bone_points(scene, frames, max_points: int = 1500) -> dict:
    """Per bone of ``scene``, per view, the ideal pixels ``(n, 2)`` of its voxels (at most
    ``max_points`` of its mask) at the true poses of ``frames``, those inside the field
    (within 0.95 of the distortion's radius): where the bone's image lies in the trial."""
    from core.tracking.bones import bone_model

    out = {}
    for b, bone in enumerate(scene.bones):
        m = bone_model(bone, mesh=False)
        k, j, i = np.nonzero(m.mask)
        P = m.volume.index_to_physical(np.column_stack([i, j, k]).astype(float))
        P = P[:: max(1, len(P) // max_points)]
        views = []
        for cam, im in zip(scene.rig, scene.imaging, strict=True):
            d = im.distortion
            uv = np.concatenate([cam.project(P @ T[:3, :3].T + T[:3, 3])
                                 for T in (scene.poses(f)[b] for f in frames)])
            views.append(uv[np.hypot(uv[:, 0] - d.center[0], uv[:, 1] - d.center[1]) < 0.95 * d.scale_px])
        out[m.name] = views
    return out


def bone_residuals(scene, corrections, points: dict) -> dict:
    """Per bone the RMS residual distortion (mm at the rig's centre, as it is) over its image
    (:func:`bone_points`), per view and over both."""
    out = {}
    for name, views in points.items():
        per, sq, n = [], 0.0, 0
        for cam, im, c, uv in zip(scene.rig, scene.imaging, corrections, views, strict=True):
            _, depth = cam.project(np.zeros((1, 3)), return_depth=True)
            e = np.linalg.norm(c.inverse(im.distortion.forward(uv)) - uv, axis=1) * float(depth[0]) / cam.fx
            per.append(float(np.sqrt(np.mean(e**2))) if len(e) else None)
            sq, n = sq + float(np.sum(e**2)), n + len(e)
        out[name] = {"rms_mm": float(np.sqrt(sq / n)) if n else None, "views_rms_mm": per}
    return out


def _pooled(rows: list[dict]) -> dict:
    """RMS over the views' points pooled (as residual_distortion_mm), max over the views."""
    out = {}
    for k in ("raw", "similarity_removed"):
        w = np.array([r["points"] for r in rows], float)
        w /= w.sum()
        out[k] = {f"{s}_{u}": float(np.sqrt(np.sum(w * np.array([r[k][f"rms_{u}"] ** 2 for r in rows]))))
                  if s == "rms" else max(r[k][f"max_{u}"] for r in rows)
                  for s in ("rms", "max") for u in ("mm", "px")}
    return out


def model_corrections(scene, residual: float = 0.03) -> list:
    """Per view of ``scene`` its true distortion with ``k1`` and the twist scaled by ``1 + residual``
    (the acceptance trial's default correction: an assumed calibration error)."""
    from core.synthetic import Distortion

    out = []
    for m in scene.imaging:
        d = m.distortion
        out.append(Distortion(d.center, d.scale_px, d.k1 * (1 + residual), d.k2, d.twist_rad * (1 + residual),
                              d.twist_power))
    return out


def run(*, pixels: int = 1024, spacing: float = 0.5, n_grids=(1, 5), seed: int = 0,
        residual: float = 0.03) -> dict:
    """The study (module docs): the trial's scene at ``pixels`` (its rig and image chains; its bones
    at frames 0, 10, …, 90 for the residual over each bone's image, ``bones``)."""
    from core.synthetic import make_foot_scene

    t0 = time.perf_counter()
    scene = make_foot_scene(n_frames=100, pixels=pixels, spacing=spacing, seed=seed, names=TRIAL_BONES,
                            beads_per_bone=0, phase=(0.0, 0.6), tissue_spacing=3.0)
    out = {"study": "core.studies.tracking.grid_correction", "machine": platform.machine(),
           "pixels": pixels, "seed": seed,
           "views": [{"pixel_mm": float(c.pixel_size), "distortion": m.distortion.to_dict()}
                     for c, m in zip(scene.rig, scene.imaging, strict=True)]}
    pts = bone_points(scene, range(0, 100, 10))
    corr = model_corrections(scene, residual)
    rows = residuals(scene, corr)
    out["model"] = {"residual": residual, "views": rows, "pooled": _pooled(rows),
                    "bones": bone_residuals(scene, corr, pts)}
    for n in n_grids:
        t = time.perf_counter()
        corr = grid_corrections(scene, n_grid=int(n), seed=seed)
        dt = time.perf_counter() - t
        rows = residuals(scene, corr)
        bare = residuals(scene, [GridCorrection(c.fit) for c in corr])  # no rig-calibration stand-in
        out[f"grid_{int(n)}_frames"] = {"views": rows, "pooled": _pooled(rows),
                                        "bones": bone_residuals(scene, corr, pts),
                                        "unaligned": {"views": bare, "pooled": _pooled(bare)},
                                        "fits": [c.summary() for c in corr], "seconds": dt}
    out["total_s"] = time.perf_counter() - t0
    return out


def main(argv=None) -> int:
    p = cli.parser("core.studies.tracking.grid_correction", __doc__)
    p.add_argument("--pixels", type=int, default=1024, help="views' size (the trial's: 1024)")
    p.add_argument("--grids", default="1,5", help="numbers of grid frames per camera to compare")
    p.add_argument("--seed", type=int, default=0)
    cli.add_output(p)
    a = p.parse_args(argv)
    return cli.finish(run(pixels=a.pixels, n_grids=cli.ints(a.grids), seed=a.seed), a)


if __name__ == "__main__":
    raise SystemExit(main())
