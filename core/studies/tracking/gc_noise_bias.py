"""Why quantum noise biases the gradient correlation of magnitudes, and a cure
(``python -m core.studies.tracking.gc_noise_bias``).

On the harder acceptance trial (:mod:`core.studies.tracking.hard_trial`) the tibia is held
0.2–0.3° off about its long axis and the talus ~0.1° about x by the default cost, the Pearson
correlation of gradient *magnitudes* (:func:`core.similarity.gradient_correlation`), and the
shift comes with the frames' quantum noise. Noise adds to the fluoroscope's squared magnitudes on
average, ``E|g + n|² = |g|² + E|n|²``, and ``E|n|²`` is larger where fewer photons arrive (behind
the fibula, the hindfoot): the fluoroscope's magnitude image carries a pedestal shaped like the
inverse fluence that the DRR lacks, and the correlation favours poses that put the bone's edges
on it.

Each chosen bone is registered from its true pose (one full-resolution quadratic search of
:func:`core.tracking.register.register`, the host :class:`~core.tracking.cost.RegistrationCost`;
the other tracked bones at their true poses and subtracted, as joint tracking does) in frames of
the trial rendered without noise and with several noise draws, for these forms of the GC term:

* ``magnitudes`` — today's default;
* ``components`` — Penney's form (the term's ``components`` option);
* ``debiased`` — magnitudes, the fluoroscope's as ``sqrt(max(|g_F|² - E|g_n|², 0))``
  (:func:`core.similarity.gradient.debiased_magnitude`) with ``E|g_n|² = E₁(p) / F(p)``:
  ``E₁`` measured from two uniform calibration frames through a 0.5-transmission plate, taken
  through the same chain and corrections as the trial's frames (:func:`core.similarity.gradient.
  noise_gradient_energy`'s photon transfer: the gradient energy of their log difference, with
  the cost's smoothing and operator, smoothed into a map of the field), ``F`` the frame's
  fluence smoothed by 2 px (:func:`core.similarity.gradient.quantum_noise_energy`). Nothing
  of the generator enters but the calibration frames it renders;
* ``inflated`` (noise-free frames only) — the mechanism's test: the noise-free fluoroscope's
  magnitudes as ``sqrt(|g_F|² + E|g_n|²)``, the noisy frames' *expected* squared magnitudes. If
  it moves the optimum as the noise does on average, the pedestal is the cause.

The debiased and inflated forms are put into the cost by replacing the fluoroscope's gradient
vectors with vectors of the new length before they go to the device (the magnitude correlation
reads only their length): :func:`core.similarity.batched._smooth_and_gradient` and
:func:`core.tracking.cost.fluoro_rois` are wrapped for the study's duration. Only the
full-resolution level is used (its smoothing and sampling are what the calibration measured).
The ``np_`` forms score every DRR with a numpy copy of the device GC (``np_magnitudes`` gives the
device's optimum to the digit): ``np_debiased_var`` also takes the noise out of the fluoroscope's
second moment (``Σ(|g_F|² - E)`` in the variance), ``np_components_var`` the components' form with
``E/2`` taken out of each component's second moment, ``np_energy`` correlates squared
magnitudes, the fluoroscope's as ``|g_F|² - E`` with its second moment corrected too (for
Gaussian gradient noise every sum is then unbiased). :func:`check_energy` compares the
calibration's ``E₁/F`` with the noise's real gradient energy (noisy minus noise-free frames).

Measured on this 2-core CPU machine (shared: load average 3.0-8.9; 512², 1 mm voxels,
seed 0 of a 12-frame trial, frames 1 and 6, four noise draws each, the trial's own draw among
them; ``resources/benchmarks/tracking_gc_noise_bias_cpu.json``): the calibration predicts the
noise's gradient energy within 5 % in every band of fluence. Tibia about z (its long axis), mean
over the 8 noisy registrations: magnitudes −0.192° (noise-free −0.073°), the noise-free frames'
*expected* magnitudes (``inflated``) −0.162°, debiased −0.121°, components +0.092° (noise-free
+0.061°); RMS rotation error 0.215 / 0.161 / 0.160° (magnitudes / debiased / components). Talus
about x: magnitudes +0.140° (noise-free +0.092°), inflated +0.136°, debiased +0.094°, components
+0.058°; about y the magnitudes are −0.10° off without noise and −0.12° with it, debiased −0.12°,
components +0.005°; RMS 0.242 / 0.227 / 0.126°. So the pedestal is the mechanism (the expected
noise energy alone gives 75 % of the tibia's and 92 % of the talus's mean shift under noise) and
taking it out removes 60 % and all of it; the second-moment corrections change nothing (frame 1:
tibia −0.105° against −0.109°). What stays is the magnitudes' noise-free error (the talus about
y), which the components do not have. The calcaneus is not lost (frame 1, 4 draws: each within
0.03° of the magnitudes). At a quarter of the dose (``--dose 0.25``: each pixel as noisy as the
1024² trial's; frame 1, 3 draws) the inflated shift is −0.23° (tibia z) and debiasing takes out
about half of it (per draw +0.07 to +0.14°): ``sqrt(max(m² - E, 0))`` leaves ~0.33 √E of a
pure-noise pixel's 0.89 √E.

The tracker's option (:class:`core.tracking.register.RegistrationOptions` ``noise_correction``,
off by default) does the same on the Gauss–Newton engine and the host cost with ``E₁`` estimated
from each frame instead of calibration frames
(:func:`core.similarity.gradient.frame_noise_energy`: within 0.92-1.08 of this study's plate
calibration on the 512² frames). On one NVIDIA H200 (``resources/benchmarks/
tracking_noise_energy_h200.json``; 1024², 12 frames, newton search) it took the tibia from 0.257
to 0.199° RMS tracked sequentially and from 0.262 to 0.209° jointly, left the talus within 0.01°
and the acceptance trial unchanged, and cost 3.78 → 9.16 ms per one-bone frame.
"""

from __future__ import annotations

import argparse
import os
import platform
import time
from contextlib import contextmanager
from dataclasses import replace
from itertools import pairwise

import numpy as np

from core.studies.tracking.acceptance import pose_errors
from core.studies.tracking.hard_trial import HardRun

__all__ = ["FORMS", "NUMPY_FORMS", "calibration_energy", "check_energy", "main", "run"]

FORMS = ("magnitudes", "components", "debiased")


def _model(hr: HardRun, view: int):
    """The imaging model of ``view`` at the study's dose (``hr.dose`` × the trial's quanta)."""
    m = hr.scene.imaging[view]
    dose = getattr(hr, "dose", 1.0)
    return m if dose == 1.0 else replace(m, photons_per_pixel=m.photons_per_pixel * dose)


def _calibration_flats(hr: HardRun, view: int, *, seed: int, transmission: float = 0.5):
    """Two uniform frames of ``view`` through a plate of ``transmission``: the chain and
    corrections of the trial's frames (new noise draws)."""
    m, c = _model(hr, view), hr.corrections[view]
    cam = hr.scene.rig[view]
    L = np.full((cam.height, cam.width), -np.log(transmission))
    out = []
    for k in range(2):
        g = np.random.default_rng([seed, 0xCA1, view, k])
        # to_float clips at 1: the plate keeps the fluence well below it
        out.append(c.unwarp(m.to_float(m.apply(L, rng=g))))
    return out


def calibration_energy(hr: HardRun, view: int, sigma_px: float, ku, kv, *, seed: int = 0,
                       smooth_px: float = 12.0) -> np.ndarray:
    """``E₁(p)``: the expected squared gradient of the noise of ``view`` at full fluence, per
    pixel, from two calibration frames (the cost's smoothing ``sigma_px`` and kernels ``ku, kv``).
    """
    from scipy import ndimage

    a, b = (np.asarray(x, np.float64) for x in _calibration_flats(hr, view, seed=seed))
    ok = (a > 0.05) & (b > 0.05)
    d = np.where(ok, np.log(np.clip(b, 1e-6, None)) - np.log(np.clip(a, 1e-6, None)), 0.0)
    _, gu, gv = _ORIG["smooth"](d, sigma_px, ku, kv)
    e = 0.5 * (gu * gu + gv * gv) * 0.5 * (a + b)  # scaled to full fluence (var ∝ 1/F)
    inner = ndimage.binary_erosion(ok, iterations=4, border_value=0)
    w = ndimage.gaussian_filter(inner.astype(float), smooth_px)
    num = ndimage.gaussian_filter(np.where(inner, e, 0.0), smooth_px)
    out = np.where(w > 1e-3, num / np.maximum(w, 1e-3), 0.0)
    # outside the usable field: the nearest usable value (those pixels are masked anyway)
    fill = float(np.median(e[inner]))
    return np.where(w > 1e-3, out, fill)


_ORIG: dict = {}


def _pearson_sums(a, b, b2=None) -> float:
    """Pearson correlation from its sums over Ω (``b2``: the fluoroscope's second moments to use
    in place of ``b²``, e.g. with the noise's expected share taken out); 0 where undefined."""
    n = a.size
    if n < 2:
        return 0.0
    sa, sb = a.sum(), b.sum()
    saa = (a * a).sum() - sa * sa / n
    sbb = (b * b if b2 is None else b2).sum() - sb * sb / n
    sab = (a * b).sum() - sa * sb / n
    if saa <= 0 or sbb <= 0:
        return 0.0
    return float(sab / np.sqrt(saa * sbb))


#: forms scored by the study's numpy copy of the device metric (``np_`` forms, see :func:`_hooks`)
NUMPY_FORMS = ("np_magnitudes", "np_debiased", "np_debiased_var", "np_components_var", "np_energy")


def _numpy_score(form: str, m, ref: int, d: np.ndarray, noise: np.ndarray) -> float:
    """One DRR item against the metric's fluoroscope ROI ``ref`` as the device GC does (the DRR
    blurred by ``drr_sigma``, Ω = blurred DRR > threshold inside the mask, 3 × 3 gradients), with
    the fluoroscope side in one of :data:`NUMPY_FORMS`."""
    from scipy import ndimage

    from core.similarity.batched import gaussian_weights

    h, w = m.roi_shapes[ref]
    d = np.nan_to_num(np.asarray(d[:h, :w], np.float64))
    if m.drr_sigma > 0:
        taps = gaussian_weights(m.drr_sigma).astype(np.float64)
        d = ndimage.correlate1d(ndimage.correlate1d(d, taps, 0, mode="nearest"), taps, 1, mode="nearest")
    om = (m._study_mask[ref][:h, :w] != 0) & (d > m.threshold)
    _, du, dv = _ORIG["smooth"](d, 0.0, m._study_k[0], m._study_k[1])
    g = m._study_fgrad[ref][:h, :w]
    fu, fv = g[..., 0].astype(np.float64)[om], g[..., 1].astype(np.float64)[om]
    du, dv, e = du[om], dv[om], noise[:h, :w][om]
    if form == "np_components_var":
        return 0.5 * (_pearson_sums(du, fu, fu * fu - e / 2) + _pearson_sums(dv, fv, fv * fv - e / 2))
    m2 = fu * fu + fv * fv
    if form == "np_energy":  # E[m2 - e] = |g|², E[b² - 2be - e²] = |g|⁴ (Gaussian gradient noise)
        b = m2 - e
        return _pearson_sums(du * du + dv * dv, b, b * b - 2 * b * e - e * e)
    a = np.hypot(du, dv)
    if form == "np_magnitudes":
        return _pearson_sums(a, np.sqrt(m2))
    b = np.sqrt(np.maximum(m2 - e, 0.0))
    return _pearson_sums(a, b, m2 - e if form == "np_debiased_var" else None)


@contextmanager
def _hooks(hr: HardRun, form: str, *, seed: int = 0):
    """Within the block the cost's GC takes ``form``: ``"debiased"`` / ``"inflated"`` make the
    fluoroscope's gradient vectors ``sqrt(max(|g|² ∓ E, 0))`` long (the device metric reads only
    their length), a :data:`NUMPY_FORMS` form scores every DRR on the host
    (:func:`_numpy_score`); ``E`` the calibrated noise energy of each full-resolution region."""
    import core.similarity.batched as B
    import core.tracking.cost as C
    from core.imaging.edges import derivative_kernels
    from core.similarity.gradient import quantum_noise_energy

    side: dict[bytes, tuple] = {}
    energy: dict[tuple, np.ndarray] = {}
    collected: list = []
    orig_rois, orig_smooth = C.fluoro_rois, B._smooth_and_gradient
    orig_init, orig_eval = B.BatchedMetric.__init__, B.BatchedMetric.evaluate
    _ORIG["smooth"] = orig_smooth
    sign = {"debiased": -1.0, "inflated": 1.0}.get(form, 0.0)

    def key(a) -> bytes:
        a = np.ascontiguousarray(a, dtype=np.float32)
        return a.shape[0].to_bytes(4, "little") + a.tobytes()

    def rois(renderer, frame, *, views, roi, scale=1.0, others=None):
        out = orig_rois(renderer, frame, views=views, roi=roi, scale=scale, others=others)
        if float(scale) == 1.0:
            raw, _ = orig_rois(renderer, frame, views=views, roi=roi, scale=scale, others=None)
            r = np.asarray(roi, dtype=np.int64).reshape(len(views), 4)
            for i, v in enumerate(views):
                side[key(out[0][i])] = (int(v), r[i], np.asarray(raw[i], np.float64))
        return out

    def smooth(f, sigma, ku, kv):
        fs, gu, gv = orig_smooth(f, sigma, ku, kv)
        hit = side.get(key(f))
        if hit is None:
            raise RuntimeError("gc_noise_bias: a fluoroscope region the study did not see (pyramid level?)")
        v, (u0, v0, w, h), raw = hit
        ek = (v, float(sigma))
        if ek not in energy:
            energy[ek] = calibration_energy(hr, v, float(sigma), ku, kv, seed=seed)
        E1 = energy[ek]
        H, W = E1.shape
        rows = np.clip(np.arange(v0, v0 + h), 0, H - 1)
        cols = np.clip(np.arange(u0, u0 + w), 0, W - 1)
        e = E1[np.ix_(rows, cols)][: raw.shape[0], : raw.shape[1]]
        noise = quantum_noise_energy(np.exp(-raw), 1.0) * e
        collected.append(noise)
        if sign == 0.0:
            return fs, gu, gv
        m2 = gu * gu + gv * gv
        new = np.sqrt(np.maximum(m2 + sign * noise, 0.0))
        mag = np.sqrt(m2)
        k = np.divide(new, mag, out=np.zeros_like(mag), where=mag > 0)
        return fs, gu * k, gv * k

    def init(self, kind, fluoro_rois, **kw):
        collected.clear()
        orig_init(self, kind, fluoro_rois, **kw)
        self._study_noise = list(collected)
        self._study_fgrad = self._fgrad.numpy()
        self._study_mask = self._fmask.numpy()
        self._study_k = tuple(np.asarray(x, np.float64) for x in derivative_kernels(self.operator))

    def evaluate(self, images):
        from core.render import DRRBatch

        X = (images.images if isinstance(images, DRRBatch) else images).numpy()
        nr = self.n_refs
        Bn = X.shape[0] // nr
        item = np.array([_numpy_score(form, self, k % nr, X[k], self._study_noise[k % nr])
                         for k in range(X.shape[0])]).reshape(Bn, nr)
        w = self._weights.numpy().astype(np.float64)
        return B.BatchedScores(item @ w / w.sum(), item.reshape(Bn, self.n_views, self.n_bones))

    C.fluoro_rois, B._smooth_and_gradient = rois, smooth
    if form in NUMPY_FORMS:
        B.BatchedMetric.__init__, B.BatchedMetric.evaluate = init, evaluate
    try:
        yield
    finally:
        C.fluoro_rois, B._smooth_and_gradient = orig_rois, orig_smooth
        B.BatchedMetric.__init__, B.BatchedMetric.evaluate = orig_init, orig_eval


def check_energy(hr: HardRun, f: int, draws: int = 2, *, sigma_mm: float = 0.3, seed: int = 0) -> dict:
    """The calibration's prediction ``E₁(p)/F(p)`` against the noise's real squared gradient
    (noisy minus noise-free line integrals of frame ``f``, the cost's smoothing and Sobel), per
    view, as the ratio of their means in four bands of fluence (pixels with ``F > 0.02``)."""
    from core.imaging.edges import derivative_kernels
    from core.similarity.batched import _smooth_and_gradient
    from core.similarity.gradient import quantum_noise_energy

    _ORIG["smooth"] = _smooth_and_gradient
    ku, kv = derivative_kernels("sobel")
    sig = sigma_mm / float(hr.scene.rig[0].pixel_size)
    clean = _frames(hr, f, None)
    out = {"sigma_px": sig, "views": []}
    for v in range(len(clean)):
        E1 = calibration_energy(hr, v, sig, ku, kv, seed=seed)
        y0 = -np.log(np.clip(clean[v].astype(np.float64), 1e-6, None))
        pred = quantum_noise_energy(np.asarray(clean[v], np.float64), 1.0) * E1
        got = []
        for d in range(draws):
            y = -np.log(np.clip(_frames(hr, f, d)[v].astype(np.float64), 1e-6, None))
            _, gu, gv = _smooth_and_gradient(y - y0, sig, ku, kv)
            got.append(gu * gu + gv * gv)
        got = np.mean(got, axis=0)
        F = np.asarray(clean[v], np.float64)
        ok = F > 0.02
        edges = np.quantile(F[ok], [0, 0.25, 0.5, 0.75, 1.0])
        bands = []
        for lo, hi in pairwise(edges):
            sel = ok & (F >= lo) & (F <= hi)
            bands.append({"fluence": [round(float(lo), 3), round(float(hi), 3)],
                          "measured_over_predicted": round(float(got[sel].mean() / pred[sel].mean()), 3)})
        out["views"].append(bands)
    return out


def _frames(hr: HardRun, f: int, draw: int | None) -> list[np.ndarray]:
    """Frame ``f``: noise-free (``draw`` None), the trial's own noise (0) or another draw."""
    L = hr.line_integrals(f)
    out = []
    for v, c in enumerate(hr.corrections):
        m = _model(hr, v)
        if draw is None:
            m = replace(m, photons_per_pixel=None, read_noise_dn=0.0)
            out.append(c.unwarp(m.to_float(m.apply(L[v]))))
            continue
        g = (hr.scene.frame_rng(f, v) if draw == 0
             else np.random.default_rng([hr.scene.seed, 0xD4A, f, v, draw]))
        out.append(c.unwarp(m.to_float(m.apply(L[v], rng=g))))
    return out


def run(*, pixels: int = 512, spacing: float = 1.0, n_frames: int = 12, frames=(1,), draws: int = 3,
        bones=("tibia", "talus"), forms=FORMS, seed: int = 0, cache: str | None = None,
        progress=None, dose: float = 1.0) -> dict:
    """Errors (mm, degrees; :func:`pose_errors`) of each bone registered from its true pose per
    frame, noise draw and GC form; see the module docs. ``dose`` scales the quanta per pixel
    (0.25 at 512² gives each pixel the noise of the 1024² trial's)."""
    from core.tracking.cost import DEFAULT_TERMS, metric_terms, prepare_frame
    from core.tracking.register import FINAL_STEP, Level, RegistrationOptions, register

    t0 = time.perf_counter()
    hr = HardRun(n_frames=n_frames, pixels=pixels, spacing=spacing, seed=seed, cache=cache)
    hr.dose = float(dose)
    level = Level(scale=1.0, method="quadratic", sigma=(0.5, 1.0), max_generations=8, tol_x=0.02,
                  options={"min_step": FINAL_STEP})
    opts = {"magnitudes": RegistrationOptions(levels=(level,), search="local", bounds=(5.0, 5.0))}
    opts["components"] = replace(opts["magnitudes"], terms=metric_terms("components"))
    for f in ("debiased", "inflated", *NUMPY_FORMS):
        opts[f] = opts["magnitudes"]
    results: dict = {}
    timing = []
    for f in frames:
        truth = hr.truth(f)
        for draw in [None, *range(draws)]:
            imgs = prepare_frame(_frames(hr, f, draw))
            fs = ([x for x in forms if x not in ("debiased", "np_debiased", "np_debiased_var", "np_energy")]
                  + (["inflated"] if "debiased" in forms else []) if draw is None else list(forms))
            for form in fs:
                for name in bones:
                    b = hr.names.index(name)
                    others = [k for k in range(len(hr.names)) if k != b]
                    t1 = time.perf_counter()
                    kw = dict(bone=b, initial_pose=truth[b], center=hr.models[b].centroid, options=opts[form],
                              outline=hr.models[b].outline, others=(truth[others], others))
                    if form in ("debiased", "inflated", *NUMPY_FORMS):
                        with _hooks(hr, form, seed=seed):
                            r = register(hr.renderer, imgs, **kw)
                    else:
                        r = register(hr.renderer, imgs, **kw)
                    e = pose_errors(r.pose, truth[b], hr.models[b].centroid)
                    dt = time.perf_counter() - t1
                    timing.append(dt)
                    tag = "noise_free" if draw is None else f"draw_{draw}"
                    results.setdefault(name, {}).setdefault(form, {}).setdefault(tag, []).append(
                        {"frame": int(f), "error": np.round(e, 4).tolist(), "seconds": round(dt, 1)})
                    if progress:
                        progress(f, tag, form, name, e, dt)
    summary = {}
    for name, per in results.items():
        summary[name] = {}
        for form, tags in per.items():
            noisy = np.array([x["error"] for t, v in tags.items() if t != "noise_free" for x in v])
            clean = np.array([x["error"] for x in tags.get("noise_free", [])])
            s = {}
            if len(noisy):
                s["noisy_mean"] = {"mm": noisy[:, :3].mean(0).round(4).tolist(),
                                   "deg": noisy[:, 3:].mean(0).round(4).tolist()}
                s["noisy_rms"] = {"mm": float(np.sqrt(np.mean(np.sum(noisy[:, :3] ** 2, 1)))),
                                  "deg": float(np.sqrt(np.mean(np.sum(noisy[:, 3:] ** 2, 1))))}
                s["noisy_n"] = len(noisy)
            if len(clean):
                s["noise_free_mean"] = {"mm": clean[:, :3].mean(0).round(4).tolist(),
                                        "deg": clean[:, 3:].mean(0).round(4).tolist()}
            summary[name][form] = s
    return {"study": "core.studies.tracking.gc_noise_bias",
            "machine": platform.machine(), "processor": platform.processor() or platform.machine(),
            "cpu_count": os.cpu_count(), "load_average_at_end": list(os.getloadavg()),
            "config": {"pixels": pixels, "voxel_mm": spacing, "trial_frames": n_frames,
                       "frames": list(frames),
                       "draws": draws, "dose": dose, "bones": list(bones), "forms": list(forms), "seed": seed,
                       "search": "one quadratic search at full resolution from the true pose",
                       "terms": [t.to_dict() for t in DEFAULT_TERMS],
                       "calibration": "two uniform frames through a 0.5-transmission plate per view"},
            "summary": summary, "results": results, "registration_s_mean": float(np.mean(timing)),
            "total_s": time.perf_counter() - t0}


def main(argv=None) -> int:
    import sys

    from core.io.atomic import print_json

    p = argparse.ArgumentParser(prog="python -m core.studies.tracking.gc_noise_bias",
                                description=__doc__.split("\n")[0])
    p.add_argument("--pixels", type=int, default=512)
    p.add_argument("--voxel", type=float, default=1.0)
    p.add_argument("--trial-frames", type=int, default=12)
    p.add_argument("--frames", default="1")
    p.add_argument("--draws", type=int, default=3)
    p.add_argument("--bones", default="tibia,talus")
    p.add_argument("--forms", default=",".join(FORMS))
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--dose", type=float, default=1.0, help="scale of the quanta per pixel")
    p.add_argument("--cache", default=None)
    p.add_argument("--check-energy", action="store_true",
                   help="instead of registering: the calibration's noise energy against the frames'")
    p.add_argument("--out", default=None)
    a = p.parse_args(argv)
    if a.check_energy:
        hr = HardRun(n_frames=a.trial_frames, pixels=a.pixels, spacing=a.voxel, seed=a.seed, cache=a.cache)
        frames = [int(f) for f in a.frames.split(",")]
        print_json({f: check_energy(hr, f, max(a.draws, 1), seed=a.seed) for f in frames}, a.out)
        return 0

    def say(f, tag, form, name, e, dt):
        print(f"frame {f} {tag:10s} {form:10s} {name:9s} mm {np.round(e[:3], 3)} deg {np.round(e[3:], 3)} "
              f"{dt:.0f}s", file=sys.stderr, flush=True)

    res = run(pixels=a.pixels, spacing=a.voxel, n_frames=a.trial_frames,
              frames=tuple(int(x) for x in a.frames.split(",")), draws=a.draws,
              bones=tuple(a.bones.split(",")), forms=tuple(a.forms.split(",")), seed=a.seed,
              cache=a.cache, progress=say, dose=a.dose)
    print_json(res, a.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
