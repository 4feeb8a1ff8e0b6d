"""The per-camera work of :mod:`core.calibration.session` on the session's frames: flatfield,
distortion grid, bead-lattice check, veiling glare (the optional lead-disc frames), the correction
pipeline, and bead detection on corrected object frames.

Pixels are ``(u, v) = (column, row)``, origin at the centre of the top-left pixel; mm.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..imaging.distortion_eval import evaluate_lattice
from ..imaging.distortion_maps import undistort_image
from ..imaging.flatfield import Flatfield, build_flatfield
from ..imaging.glare import GlareEstimate, estimate_glare
from ..imaging.grid_indexing import index_grid
from ..imaging.pipeline import Pipeline
from ..markers import detect_beads
from . import _session_grid as grids
from ._session_input import DEFAULTS, SessionError, _Reader
from .detection import ObjectDetections, detect_object_beads
from .objects import CalibrationTarget


@dataclass(frozen=True, eq=False)
class CameraCorrection:
    """What the session gives one camera: flatfield, distortion fit, veiling glare (None without
    glare frames) and the correction pipeline."""

    name: str
    flatfield: Flatfield
    grid: grids.GridFit
    pipeline: Pipeline
    kv: float | None
    glare: GlareEstimate | None = None

def _correction(cam, ff, kv, fit, glare=None) -> CameraCorrection:
    pipe = Pipeline.standard(flatfield=ff, dark=ff.dark, glare=glare, distortion=fit.model)
    pipe.prepare(ff.shape)
    return CameraCorrection(cam, ff, fit, pipe, kv, glare)


def _glare(rd: _Reader, cam: str, ff: Flatfield, flat_group: str, fit, progress) -> GlareEstimate | None:
    """Veiling glare from the camera's lead-disc frames (None when the session has none): their
    mean over the mean empty field (dark subtracted, not smoothed or clipped: the smoothed
    fluence surface would bias the glare's faint profile), undistorted by the fitted model,
    measured by :func:`core.imaging.glare.estimate_glare` inside the field."""
    import cv2

    refs = rd.refs(cam, "glare", required=False)
    if not refs:
        return None
    dark = np.asarray(ff.dark, np.float64)
    disc = np.mean([rd.read(cam, r, k, "glare") for k, r in enumerate(refs)], axis=0) - dark
    flats = rd.refs(cam, flat_group)
    flat = np.mean([rd.read(cam, r, k, "glare") for k, r in enumerate(flats)], axis=0) - dark
    field = ff.valid & (ff.gain > 0.5 * np.percentile(ff.gain[ff.valid], 99)) & (flat > 0)
    img = np.where(field, disc / np.where(field, flat, 1.0), 0.0).astype(np.float32)
    img = undistort_image(img, fit.model)
    inside = undistort_image(field.astype(np.float32), fit.model) > 0.99
    inside = cv2.erode(inside.astype(np.uint8), np.ones((25, 25), np.uint8)).astype(bool)
    progress(f"glare {cam}", 1, 1)
    try:
        return replace(estimate_glare(img, mask=inside), n_frames=len(refs))
    except ValueError as exc:
        raise SessionError("glare", f"{refs[0]} (camera {cam}, {len(refs)} disc frames)", str(exc),
                           "record the lead disc whole and inside the field, or remove the 'glare' "
                           "frames from the session") from None


def _flatfield(rd: _Reader, cam: str, groups, kv, progress) -> tuple[Flatfield, float | None]:
    darks = rd.refs(cam, "dark")
    dark = np.mean([rd.read(cam, r, k, "flatfield") for k, r in enumerate(darks)], axis=0)
    if not groups:
        raise SessionError("flatfield", f"camera {cam}", "no empty-field (flat) frames in the session",
                           "record empty-field frames at the trial's kV")
    pick = groups[0] if kv is None else min(groups, key=lambda g: abs((g[0] or 0) - kv))
    refs = rd.refs(cam, pick[1])
    flats = [rd.read(cam, r, k, "flatfield") for k, r in enumerate(refs)]
    progress(f"flatfield {cam}", 1, 1)
    ff = build_flatfield(np.stack(flats), dark=dark, method="max", kernel_size=15, kv=pick[0])
    bad = ff.n_invalid / ff.gain.size
    if bad > 0.5:
        raise SessionError("flatfield", f"camera {cam}, {refs[0]}",
                           f"{100 * bad:.0f} % of the field has no signal above the dark frames",
                           "check that the empty-field frames were taken with the beam on")
    return ff, pick[0]


def _distortion(rd: _Reader, cam: str, ff: Flatfield, *, model, pitch, feature_mm, px_mm, progress):
    refs = rd.refs(cam, "grid")
    feat = feature_mm / px_mm
    found = []
    for k, r in enumerate(refs):
        img = ff.normalise(rd.read(cam, r, k, "distortion"))
        c = ((img.shape[1] - 1) / 2, (img.shape[0] - 1) / 2)
        try:
            found.append(grids.detect_frame(img, k, pitch_mm=pitch, feature_px=feat, center=c))
        except grids.GridFrameError as exc:
            raise SessionError("distortion", f"{r} (grid frame {k} of camera {cam})", str(exc),
                               "check that the grid lies on the intensifier in this frame, remove the "
                               f"frame, or give the grid's pitch ({pitch:g} mm) and hole diameter "
                               f"({feature_mm:g} mm) in the session manifest") from None
        progress(f"distortion {cam}", k + 1, len(refs))
    pl = grids.merge_placements(found)
    try:
        return grids.fit_view(pl, model=model, pitch_mm=pitch, center=c, n_frames=len(refs)), pl
    except ValueError as exc:
        raise SessionError("distortion", f"camera {cam} ({len(refs)} grid frames)", str(exc),
                           "use a lower-order model (--model poly 4,4) or add grid frames") from None


def _lattice(rd: _Reader, cam: str, c: CameraCorrection, man: dict) -> dict | None:
    """Bead-lattice frames (optional): inter-bead distance and right-angle errors after the
    view's correction (thesis Tables 3.2-3.3), an independent check of the distortion model."""
    refs = rd.refs(cam, "lattice", required=False)
    if not refs:
        return None
    lat = man.get("lattice") or {}
    pitch = float(lat.get("pitch_mm", 20.0))
    bead_px = float(lat.get("bead_diameter_mm", 2.0)) / c.grid.mm_per_px
    found, failed = [], []
    for k, r in enumerate(refs):
        img = c.flatfield.normalise(rd.read(cam, r, k, "distortion"))
        try:
            pts = detect_beads(img, diameter_px=bead_px, polarity="dark", mask=lit_field(c.flatfield))
            gi = index_grid(pts.uv, min_points=9)
            found.append((gi.uv, gi.ij))
        except ValueError as exc:
            failed.append(f"{r} (lattice frame {k}): {exc}")
    out: dict = {"frames": len(refs), "pitch_mm": pitch, "failed": failed}
    if found:
        e = evaluate_lattice(c.grid.model, found, pitch_mm=pitch, mm_per_px=c.grid.mm_per_px)
        out.update(e.to_dict(), beads=int(sum(len(uv) for uv, _ in found)))
    return out


def _detect(img: np.ndarray, target: CalibrationTarget, ppm: float, mask) -> ObjectDetections:
    # the strongest detections are enough (a few missed or extra beads are labelled around):
    # the labelling's cost grows with detections x beads x hypotheses
    return detect_object_beads(img, target.size_classes[0], px_per_mm=ppm, mask=mask,
                               max_beads=2 * len(target) + 10,
                               flatten_background=target.body is not None and target.body[0] == "tube")


#: The field: where the fluence surface exceeds this fraction of its 99th percentile.
FIELD_GAIN = 0.2


def lit_field(ff: Flatfield) -> np.ndarray:
    """Raw pixels inside the intensifier's field: a fluence surface above ``FIELD_GAIN`` of its
    99th percentile. ``Flatfield.valid`` (any positive surface) is not the field: the "max"
    surface follows the dark noise's upper envelope outside the round field, a positive
    fraction of a percent of the field's, and the noise normalised there (clipped to [0, 1])
    is a carpet of dark blobs of every size."""
    g = ff.gain[ff.valid]
    if g.size == 0:
        return ff.valid
    return ff.valid & (ff.gain > FIELD_GAIN * float(np.percentile(g, 99)))


def _field_mask(c: CameraCorrection, margin_px: int = 12) -> np.ndarray:
    """Corrected-image pixels inside the intensifier's field, ``margin_px`` from its rim."""
    import cv2

    undist = next(s for s in c.pipeline.steps if getattr(s, "kind", "") == "undistort")
    inside = undist(lit_field(c.flatfield).astype(np.float32)) > 0.99
    k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * margin_px + 1, 2 * margin_px + 1))
    return cv2.erode(inside.astype(np.uint8), k).astype(bool)


def _scale(img: np.ndarray, target: CalibrationTarget, px_mm: float, mask) -> float:
    """Projected px per bead-mm: the magnification that classifies the most beads of a frame."""
    best = (-1, 1.5 / px_mm)
    for mag in DEFAULTS["magnification"]:
        d = _detect(img, target, mag / px_mm, mask)
        n = int(np.sum(d.size_class >= 0))
        if n > best[0]:
            best = (n, d.px_per_mm if np.isfinite(d.px_per_mm) else mag / px_mm)
    return best[1]


def _beads(rd: _Reader, cams, corr, group: str, target, progress, *, required=True):
    refs = [rd.refs(c, group, required=required) for c in cams]
    n = len(refs[0])
    for c, r in zip(cams, refs, strict=True):
        if len(r) != n:
            raise SessionError("beads", f"{group!r} frames", f"camera {cams[0]} has {n} frames but camera "
                               f"{c} has {len(r)}", "both views of every object pose are needed")
    ppm = [None] * len(cams)
    masks = [_field_mask(c) for c in corr]
    dets = []
    for k in range(n):
        pair = []
        for v, c in enumerate(cams):
            img = corr[v].pipeline(rd.read(c, refs[v][k], k, "beads"))
            if ppm[v] is None:
                ppm[v] = _scale(img, target, corr[v].grid.mm_per_px, masks[v])
            pair.append(_detect(img, target, ppm[v], masks[v]))
        dets.append(tuple(pair))
        progress(f"beads {group}", k + 1, n)
    return refs, dets
