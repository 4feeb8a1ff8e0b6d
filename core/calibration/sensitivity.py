"""Sensitivity of DLT camera parameters to bead localisation noise (thesis §5.2.1, Table 5.1).

* :func:`perturbation_study`: Monte Carlo / Latin-hypercube perturbation of the image
  coordinates of a calibration object's beads (``mode="one"``: one bead at a time by an amplitude
  drawn in 0.01-0.25 px in a random direction, as the thesis did in Dakota; ``mode="all"``:
  every coordinate with Gaussian noise of that standard deviation); each sample is calibrated
  by the DLT and the deviation of every camera parameter from the noise-free calibration is
  kept. :meth:`PerturbationStudy.spread` summarises it per amplitude bin.
* :func:`sobol_analysis`: Sobol first-order and total indices of every camera parameter with
  respect to every bead coordinate (inputs uniform in ±``amplitude`` px) with
  :func:`scipy.stats.sobol_indices` (Saltelli 2010 estimators).

All DLTs of a study run at once (:func:`core.calibration.dlt.dlt_batch`). Parameters: ``f``
(px) and ``sid`` (mm, ``f`` x pixel size), principal point ``cu, cv`` (px), source position
``X, Y, Z`` (mm, lab), orientation errors ``rx, ry, rz`` (rad, rotation vector of
``R_est R_trueᵀ``: small rotations about the camera axes), and the reprojection RMS (px).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
from scipy.stats import qmc, sobol_indices, uniform

from .._validate import as_float_array, positive
from ..geometry.camera import Camera
from . import _so3
from .dlt import camera_parameters, dlt_batch

__all__ = ["PARAMETERS", "PerturbationStudy", "SobolResult", "perturbation_study", "sobol_analysis"]

#: Camera parameters reported by the sensitivity analyses, with units.
PARAMETERS = {"f": "px", "sid": "mm", "cu": "px", "cv": "px", "X": "mm", "Y": "mm", "Z": "mm",
              "rx": "rad", "ry": "rad", "rz": "rad"}


def _params(P: np.ndarray, ref: dict, pixel_size: float) -> np.ndarray:
    """``(10, B)`` parameter deviations of ``P (B, 3, 4)`` from the reference parameters."""
    p = camera_parameters(P)
    rot = _so3.log(p["R"] @ ref["R"][0].T)
    out = np.stack([p["f"] - ref["f"][0], (p["f"] - ref["f"][0]) * pixel_size,
                    p["cu"] - ref["cu"][0], p["cv"] - ref["cv"][0],
                    *(p["source"] - ref["source"][0]).T, *rot.T])
    return out


def _check(camera: Camera, points) -> tuple[np.ndarray, np.ndarray, dict, float]:
    if not isinstance(camera, Camera):
        raise ValueError(f"camera: expected a Camera, got {type(camera).__name__}")
    X = as_float_array(points, "points", shape=(None, 3))
    if len(X) < 6:
        raise ValueError(f"points: expected at least 6 beads, got {len(X)}")
    uv0 = camera.project(X)
    ref = camera_parameters(dlt_batch(X, uv0[None]))
    return X, uv0, ref, camera.pixel_size or 1.0


@dataclass(frozen=True, eq=False)
class PerturbationStudy:
    """Samples of :func:`perturbation_study`.

    ``amplitude (S,)`` px, ``marker (S,)`` perturbed bead (-1: all), ``deviation (10, S)``
    parameter minus noise-free value (order of :data:`PARAMETERS`), ``reprojection_rms (S,)`` px.
    """

    amplitude: np.ndarray
    marker: np.ndarray
    deviation: np.ndarray
    reprojection_rms: np.ndarray
    mode: str

    def parameter(self, name: str) -> np.ndarray:
        """``(S,)`` deviations of one parameter (see :data:`PARAMETERS`)."""
        if name not in PARAMETERS:
            raise ValueError(f"name: expected one of {list(PARAMETERS)}, got {name!r}")
        return self.deviation[list(PARAMETERS).index(name)]

    def spread(self, bins=(0.01, 0.05, 0.1, 0.15, 0.2, 0.25)) -> dict:
        """Per parameter and amplitude bin: standard deviation, 95th percentile of the absolute
        deviation, largest absolute deviation and peak-to-peak range; plus the overall values."""
        edges = np.asarray(bins, dtype=float)
        out = {}
        for name, unit in PARAMETERS.items():
            d = self.parameter(name)
            rows = []
            for lo, hi in itertools.pairwise(edges):
                m = (self.amplitude >= lo) & (self.amplitude <= hi)
                x = d[m]
                rows.append({"amplitude_px": [float(lo), float(hi)], "n": int(m.sum()),
                             "std": float(x.std()) if x.size else None,
                             "p95_abs": float(np.percentile(np.abs(x), 95)) if x.size else None,
                             "max_abs": float(np.abs(x).max()) if x.size else None})
            out[name] = {"unit": unit, "std": float(d.std()), "range": float(np.ptp(d)),
                         "max_abs": float(np.abs(d).max()), "by_amplitude": rows}
        r = self.reprojection_rms
        out["reprojection_rms"] = {"unit": "px", "mean": float(r.mean()), "max": float(r.max())}
        return out


def perturbation_study(camera: Camera, points, *, n_samples: int = 5000, amplitude=(0.01, 0.25),
                       mode: str = "one", rng=0) -> PerturbationStudy:
    """Latin-hypercube perturbation of the beads' image coordinates -> DLT parameter spread.

    Parameters
    ----------
    camera : Camera
        The true camera (projects the beads).
    points : (N, 3) array
        Bead centres in the lab, mm (N >= 6, non-coplanar).
    n_samples : int
        Number of perturbed calibrations.
    amplitude : (lo, hi)
        Range of the perturbation amplitude, px (sampled uniformly by the Latin hypercube).
    mode : {"one", "all"}
        ``"one"``: bead ``i mod N`` of sample ``i`` moves by the amplitude in a random direction
        (the thesis' one-at-a-time design); ``"all"``: every coordinate gets Gaussian noise of
        standard deviation equal to the amplitude.
    rng : int or Generator
        Seed of the Latin hypercube and the Gaussian draws.
    """
    X, uv0, ref, px = _check(camera, points)
    if mode not in ("one", "all"):
        raise ValueError(f"mode: expected 'one' or 'all', got {mode!r}")
    if int(n_samples) != n_samples or n_samples < 1:
        raise ValueError(f"n_samples: expected a positive integer, got {n_samples!r}")
    lo, hi = (positive(a, "amplitude") for a in amplitude)
    if not lo <= hi:
        raise ValueError(f"amplitude: expected lo <= hi, got {amplitude!r}")
    g = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
    S, N = int(n_samples), len(X)
    lhs = qmc.LatinHypercube(d=2, rng=g).random(S)
    amp = lo + (hi - lo) * lhs[:, 0]
    uv = np.broadcast_to(uv0, (S, N, 2)).copy()
    if mode == "one":
        marker = np.arange(S) % N
        phi = 2 * np.pi * lhs[:, 1]
        uv[np.arange(S), marker] += amp[:, None] * np.column_stack([np.cos(phi), np.sin(phi)])
    else:
        marker = np.full(S, -1)
        uv += amp[:, None, None] * g.normal(size=(S, N, 2))
    dev, rms = [], []
    for s in range(0, S, 4096):
        P = dlt_batch(X, uv[s : s + 4096])
        dev.append(_params(P, ref, px))
        h = np.einsum("bij,nj->bni", P, np.column_stack([X, np.ones(N)]))
        e = h[..., :2] / h[..., 2:] - uv[s : s + 4096]
        rms.append(np.sqrt(np.mean(np.sum(e**2, axis=2), axis=1)))
    return PerturbationStudy(amp, marker, np.concatenate(dev, axis=1), np.concatenate(rms), mode)


@dataclass(frozen=True, eq=False)
class SobolResult:
    """Result of :func:`sobol_analysis`.

    ``first_order``, ``total`` ``(10, 2N)``: indices of each parameter (rows, order of
    :data:`PARAMETERS`) for each input (``u`` and ``v`` of bead 0, 1, ...); ``inputs`` their names;
    ``n_evaluations`` DLTs computed; ``std (10,)`` standard deviation of each parameter over the
    base samples.
    """

    first_order: np.ndarray
    total: np.ndarray
    inputs: tuple[str, ...]
    n_evaluations: int
    std: np.ndarray

    def table(self) -> dict:
        """Per parameter (Table 5.1 analogue): the largest first-order and total index and the
        input they belong to, the sum of first-order indices (≈1 for an additive response), and
        the largest per-bead total index (u and v summed)."""
        out = {}
        for k, name in enumerate(PARAMETERS):
            s1, st = self.first_order[k], self.total[k]
            bead_total = st[0::2] + st[1::2]
            out[name] = {"max_first_order": float(s1.max()),
                         "max_first_order_input": self.inputs[int(s1.argmax())],
                         "max_total": float(st.max()), "max_total_input": self.inputs[int(st.argmax())],
                         "sum_first_order": float(s1.sum()), "max_bead_total": float(bead_total.max()),
                         "std": float(self.std[k]), "unit": PARAMETERS[name]}
        return out


def sobol_analysis(camera: Camera, points, *, amplitude: float = 0.25, n: int = 1024, rng=0) -> SobolResult:
    """Sobol indices of the DLT camera parameters w.r.t. every bead image coordinate.

    Inputs are independent, uniform in ``[-amplitude, +amplitude]`` px; ``n`` (a power of 2)
    base samples give ``n (2N + 2)`` DLT evaluations.
    """
    X, uv0, ref, px = _check(camera, points)
    a = positive(amplitude, "amplitude")
    if int(n) != n or n < 2 or (int(n) & (int(n) - 1)):
        raise ValueError(f"n: expected a power of 2, got {n!r}")
    N = len(X)
    d = 2 * N

    def func(x):  # x (d, B) -> (10, B)
        B = x.shape[1]
        out = np.empty((len(PARAMETERS), B))
        for s in range(0, B, 4096):
            pert = x[:, s : s + 4096].T.reshape(-1, N, 2)
            out[:, s : s + 4096] = _params(dlt_batch(X, uv0[None] + pert), ref, px)
        return out

    g = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
    res = sobol_indices(func=func, n=int(n), dists=[uniform(loc=-a, scale=2 * a)] * d, rng=g)
    base = func(g.uniform(-a, a, (d, int(n))))
    names = tuple(f"bead{k}.{c}" for k in range(N) for c in ("u", "v"))
    return SobolResult(np.asarray(res.first_order), np.asarray(res.total_order), names,
                       int(n) * (d + 2), base.std(axis=1))
