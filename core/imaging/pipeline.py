"""A composable, serialisable correction chain: dark → flatfield → glare → deblur → undistort.

Each step is a small frozen dataclass with ``__call__(frame) -> frame``; a :class:`Pipeline` is a
tuple of steps applied in order (the thesis's order by default, :meth:`Pipeline.standard`).
Frames are processed lazily, one at a time, with no intermediate files: :meth:`Pipeline.map`
pulls frames from any iterable (a list, a memory-mapped stack, a video reader's generator),
runs them on a thread pool (OpenCV and NumPy release the GIL) with a bounded number in flight,
and yields the results in input order. ``progress(done, total)`` is called after each frame
(``total`` is None for an iterable without a length) and ``cancel()`` is polled before each
frame is submitted and each result is handed over; on cancel, pending work is dropped and the
generator ends (:meth:`Pipeline.run` reports whether it was cancelled).

Serialisation: :meth:`Pipeline.to_dict` gives plain JSON types (arrays such as the flatfield go
through ``array_encoder``, inline base64 by default; see :mod:`core.imaging.serialize`), so the
study store can save the parameters with the study and :meth:`Pipeline.from_dict` rebuild the
same chain.

Conventions: raw frames are camera DN; after :class:`FlatfieldStep` frames are float32 ``I/I0`` in
[0, 1]; pixels ``(u, v) = (column, row)``, origin at the centre of the top-left pixel.

Order: veiling glare (:class:`GlareStep`, :mod:`core.imaging.glare`) spreads the fluence before
the intensifier's distortion and the log, and the empty field carries it uniformly, so it is undone
right after the flatfield division, on the linear fluence, before deblurring and undistortion.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from .deconvolution import richardson_lucy, richardson_lucy_varying
from .distortion_maps import remap_tables, undistort_image
from .distortion_models import DistortionModel
from .flatfield import Flatfield
from .glare import remove_glare
from .psf import PSFGrid, normalise_psf
from .serialize import decode_array, encode_array

__all__ = ["DarkStep", "DeblurStep", "FlatfieldStep", "GlareStep", "Pipeline", "PipelineRun", "UndistortStep"]

#: 2: the glare step (chains without one are still written as version 1)
PIPELINE_VERSION = 2


@dataclass(frozen=True, eq=False)
class DarkStep:
    """Subtract a dark level or dark frame (DN); output float32."""

    dark: float | np.ndarray

    kind = "dark"

    def __call__(self, frame) -> np.ndarray:
        return np.asarray(frame, dtype=np.float32) - np.asarray(self.dark, dtype=np.float32)

    def to_dict(self, *, array_encoder=encode_array) -> dict:
        d = float(self.dark) if np.ndim(self.dark) == 0 else array_encoder(np.asarray(self.dark))
        return {"kind": self.kind, "dark": d}

    @classmethod
    def from_dict(cls, d: dict, *, array_decoder=decode_array) -> DarkStep:
        x = d["dark"]
        return cls(float(x) if isinstance(x, int | float) else np.asarray(array_decoder(x), np.float32))


@dataclass(frozen=True, eq=False)
class FlatfieldStep:
    """Divide dark-subtracted frames by the flatfield's fluence surface → float32 [0, 1]."""

    flatfield: Flatfield

    kind = "flatfield"

    def __call__(self, frame) -> np.ndarray:
        return self.flatfield.divide(frame)

    def to_dict(self, *, array_encoder=encode_array) -> dict:
        return {"kind": self.kind, "flatfield": self.flatfield.to_dict(array_encoder=array_encoder)}

    @classmethod
    def from_dict(cls, d: dict, *, array_decoder=decode_array) -> FlatfieldStep:
        return cls(Flatfield.from_dict(d["flatfield"], array_decoder=array_decoder))


@dataclass(frozen=True, eq=False)
class GlareStep:
    """Undo veiling glare of ``fraction`` and Gaussian width ``sigma_px`` on flatfield-normalised
    frames (:func:`core.imaging.glare.remove_glare`: FFT on a downsampled grid); build it from a
    measured :class:`~core.imaging.glare.GlareEstimate` with :meth:`from_estimate`."""

    fraction: float
    sigma_px: float
    downsample: int | None = None
    clip: tuple[float, float] | None = (0.0, 1.0)

    kind = "glare"

    def __post_init__(self) -> None:
        if not 0 <= float(self.fraction) < 1:
            raise ValueError(f"fraction: expected a glare fraction in [0, 1), got {self.fraction!r}")
        if not float(self.sigma_px) > 0:
            raise ValueError(f"sigma_px: expected a width > 0 in pixels, got {self.sigma_px!r}")
        if self.downsample is not None and (int(self.downsample) != self.downsample or self.downsample < 1):
            raise ValueError(f"downsample: expected an integer >= 1 or None, got {self.downsample!r}")

    @classmethod
    def from_estimate(cls, estimate, **kw) -> GlareStep:
        """The step of a :class:`~core.imaging.glare.GlareEstimate` (or anything with ``fraction``
        and ``sigma_px``)."""
        return cls(float(estimate.fraction), float(estimate.sigma_px), **kw)

    def __call__(self, frame) -> np.ndarray:
        return remove_glare(frame, self.fraction, self.sigma_px, downsample=self.downsample, clip=self.clip)

    def to_dict(self, *, array_encoder=encode_array) -> dict:
        return {"kind": self.kind, "fraction": float(self.fraction), "sigma_px": float(self.sigma_px),
                "downsample": None if self.downsample is None else int(self.downsample),
                "clip": None if self.clip is None else [float(c) for c in self.clip]}

    @classmethod
    def from_dict(cls, d: dict, *, array_decoder=decode_array) -> GlareStep:
        clip = None if d.get("clip") is None else tuple(float(c) for c in d["clip"])
        ds = d.get("downsample")
        return cls(float(d["fraction"]), float(d["sigma_px"]), None if ds is None else int(ds), clip)


@dataclass(frozen=True, eq=False)
class DeblurStep:
    """Richardson–Lucy with one PSF (``(k, k)`` array) or a :class:`PSFGrid` (spatially varying)."""

    psf: np.ndarray | PSFGrid
    iterations: int = 10
    damping: float = 0.0
    photons_per_unit: float | None = None
    clip: tuple[float, float] | None = (0.0, 1.0)

    kind = "deblur"

    def __post_init__(self) -> None:
        if not isinstance(self.psf, PSFGrid):
            object.__setattr__(self, "psf", normalise_psf(self.psf))
        if int(self.iterations) != self.iterations or self.iterations < 0:
            raise ValueError(f"iterations: expected an integer >= 0, got {self.iterations!r}")
        if self.damping > 0 and self.photons_per_unit is None:
            raise ValueError("photons_per_unit: needed with damping > 0")

    def __call__(self, frame) -> np.ndarray:
        kw = {"iterations": self.iterations, "damping": self.damping,
              "photons_per_unit": self.photons_per_unit, "clip": self.clip}
        if isinstance(self.psf, PSFGrid):
            return richardson_lucy_varying(frame, self.psf, **kw)
        return richardson_lucy(frame, self.psf, **kw)

    def to_dict(self, *, array_encoder=encode_array) -> dict:
        psf = (self.psf.to_dict(array_encoder=array_encoder) if isinstance(self.psf, PSFGrid)
               else array_encoder(self.psf))
        return {"kind": self.kind, "psf": psf, "iterations": int(self.iterations),
                "damping": float(self.damping), "photons_per_unit": self.photons_per_unit,
                "clip": None if self.clip is None else [float(c) for c in self.clip]}

    @classmethod
    def from_dict(cls, d: dict, *, array_decoder=decode_array) -> DeblurStep:
        p = d["psf"]
        grid = isinstance(p, dict) and p.get("type") == "psf_grid"
        psf = (PSFGrid.from_dict(p, array_decoder=array_decoder) if grid
               else np.asarray(array_decoder(p), float))
        clip = None if d.get("clip") is None else tuple(float(c) for c in d["clip"])
        return cls(psf, int(d["iterations"]), float(d["damping"]), d.get("photons_per_unit"), clip)


@dataclass(frozen=True, eq=False)
class UndistortStep:
    """Resample frames onto the ideal pixel grid of a :class:`DistortionModel` (cached maps)."""

    model: DistortionModel
    interpolation: str = "linear"
    border: str = "constant"
    border_value: float = 0.0
    step: int = 1

    kind = "undistort"

    def prepare(self, shape) -> None:
        remap_tables(self.model, shape, step=self.step)

    def __call__(self, frame) -> np.ndarray:
        return undistort_image(frame, self.model, interpolation=self.interpolation, border=self.border,
                               border_value=self.border_value, step=self.step)

    def to_dict(self, *, array_encoder=encode_array) -> dict:
        return {"kind": self.kind, "model": self.model.to_dict(), "interpolation": self.interpolation,
                "border": self.border, "border_value": float(self.border_value), "step": int(self.step)}

    @classmethod
    def from_dict(cls, d: dict, *, array_decoder=decode_array) -> UndistortStep:
        return cls(DistortionModel.from_dict(d["model"]), d["interpolation"], d["border"],
                   float(d["border_value"]), int(d["step"]))


STEP_TYPES = {c.kind: c for c in (DarkStep, FlatfieldStep, GlareStep, DeblurStep, UndistortStep)}


@dataclass(frozen=True)
class PipelineRun:
    """What :meth:`Pipeline.run` did: frames delivered, frames known in total, cancelled or not."""

    n_done: int
    n_total: int | None
    cancelled: bool


@dataclass(frozen=True, eq=False)
class Pipeline:
    """An ordered tuple of correction steps (see the module docs)."""

    steps: tuple = ()

    def __post_init__(self) -> None:
        steps = tuple(self.steps)
        for i, s in enumerate(steps):
            if type(s) not in STEP_TYPES.values():
                raise ValueError(f"steps[{i}]: expected DarkStep, FlatfieldStep, GlareStep, DeblurStep "
                                 f"or UndistortStep, got {type(s).__name__}")
            if isinstance(s, FlatfieldStep) and np.any(np.asarray(s.flatfield.dark) != 0) \
                    and not any(isinstance(p, DarkStep) for p in steps[:i]):
                raise ValueError(f"steps[{i}]: the flatfield was built with a dark level; put a DarkStep "
                                 f"with it before the FlatfieldStep (Pipeline.standard does)")
        object.__setattr__(self, "steps", steps)

    @classmethod
    def standard(cls, *, flatfield: Flatfield | None = None, dark=None, glare=None, psf=None,
                 iterations: int = 10,
                 damping: float = 0.0, photons_per_unit: float | None = None,
                 distortion: DistortionModel | None = None, interpolation: str = "linear") -> Pipeline:
        """dark → flatfield → glare → deblur → undistort, each included when its input is given.

        ``dark`` defaults to the flatfield's own dark level; ``glare`` is a
        :class:`~core.imaging.glare.GlareEstimate` (or a :class:`GlareStep`).
        """
        steps: list = []
        dk = dark if dark is not None else (flatfield.dark if flatfield is not None else None)
        if dk is not None and np.any(np.asarray(dk) != 0):
            steps.append(DarkStep(dk))
        if flatfield is not None:
            steps.append(FlatfieldStep(flatfield))
        if glare is not None:
            steps.append(glare if isinstance(glare, GlareStep) else GlareStep.from_estimate(glare))
        if psf is not None:
            steps.append(DeblurStep(psf, iterations, damping, photons_per_unit))
        if distortion is not None:
            steps.append(UndistortStep(distortion, interpolation))
        return cls(tuple(steps))

    def prepare(self, shape) -> None:
        """Precompute what steps cache (the remap tables) for frames of ``shape``."""
        for s in self.steps:
            if hasattr(s, "prepare"):
                s.prepare(shape)

    def apply(self, frame) -> np.ndarray:
        """Run every step on one 2-D frame; float32 result."""
        x = np.asarray(frame)
        if x.ndim != 2:
            raise ValueError(f"frame: expected a 2-D frame, got shape {x.shape}")
        for s in self.steps:
            x = s(x)
        return np.asarray(x, dtype=np.float32)

    __call__ = apply

    def map(self, frames: Iterable, *, workers: int = 1,
            progress: Callable[[int, int | None], None] | None = None,
            cancel: Callable[[], bool] | None = None,
            max_in_flight: int | None = None) -> Iterator[np.ndarray]:
        """Lazily corrected frames, in input order (see the module docs).

        ``workers`` threads (1 = in the caller's thread); at most ``max_in_flight`` frames
        (default ``2 × workers``) are read ahead.
        """
        if int(workers) != workers or workers < 1:
            raise ValueError(f"workers: expected an integer >= 1, got {workers!r}")
        total = len(frames) if hasattr(frames, "__len__") else None
        limit = int(max_in_flight) if max_in_flight is not None else 2 * int(workers)
        if limit < 1:
            raise ValueError(f"max_in_flight: expected >= 1, got {max_in_flight!r}")
        stopped = cancel if cancel is not None else (lambda: False)
        it = iter(frames)
        done = 0
        if workers == 1:
            for f in it:
                if stopped():
                    return
                out = self.apply(f)
                if stopped():
                    return
                done += 1
                yield out
                if progress is not None:
                    progress(done, total)
            return
        pool = ThreadPoolExecutor(max_workers=int(workers), thread_name_prefix="talus-pipeline")
        pending: list[Future] = []
        try:
            exhausted = False
            while True:
                while not exhausted and len(pending) < limit and not stopped():
                    try:
                        f = next(it)
                    except StopIteration:
                        exhausted = True
                        break
                    pending.append(pool.submit(self.apply, f))
                if not pending or stopped():
                    return
                out = pending.pop(0).result()
                if stopped():
                    return
                done += 1
                yield out
                if progress is not None:
                    progress(done, total)
        finally:
            for p in pending:
                p.cancel()
            pool.shutdown(wait=True, cancel_futures=True)

    def run(self, frames: Iterable, sink: Callable[[int, np.ndarray], None], *, workers: int = 1,
            progress: Callable[[int, int | None], None] | None = None,
            cancel: Callable[[], bool] | None = None) -> PipelineRun:
        """Correct ``frames`` and hand each result to ``sink(index, frame)`` in order."""
        total = len(frames) if hasattr(frames, "__len__") else None
        n = 0
        for n, out in enumerate(self.map(frames, workers=workers, progress=progress, cancel=cancel), start=1):
            sink(n - 1, out)
        cancelled = bool(cancel is not None and cancel() and (total is None or n < total))
        return PipelineRun(n, total, cancelled)

    def to_dict(self, *, array_encoder=encode_array) -> dict:
        """Plain-JSON parameters of every step (arrays via ``array_encoder``)."""
        version = PIPELINE_VERSION if any(isinstance(s, GlareStep) for s in self.steps) else 1
        return {"type": "imaging_pipeline", "version": version,
                "steps": [s.to_dict(array_encoder=array_encoder) for s in self.steps]}

    @classmethod
    def from_dict(cls, d: dict, *, array_decoder=decode_array) -> Pipeline:
        if not isinstance(d, dict) or d.get("type") != "imaging_pipeline":
            raise ValueError("d: expected a dict written by Pipeline.to_dict (type 'imaging_pipeline')")
        if int(d.get("version", 0)) > PIPELINE_VERSION:
            raise ValueError(f"d: pipeline version {d.get('version')} is newer than this Talus reads "
                             f"({PIPELINE_VERSION})")
        steps = []
        for i, s in enumerate(d.get("steps", [])):
            kind = s.get("kind") if isinstance(s, dict) else None
            if kind not in STEP_TYPES:
                raise ValueError(f"d['steps'][{i}]: unknown step kind {kind!r} "
                                 f"(expected one of {sorted(STEP_TYPES)})")
            steps.append(STEP_TYPES[kind].from_dict(s, array_decoder=array_decoder))
        return cls(tuple(steps))

    def to_json(self) -> str:
        return json.dumps(self.to_dict())

    @classmethod
    def from_json(cls, text: str) -> Pipeline:
        return cls.from_dict(json.loads(text))
