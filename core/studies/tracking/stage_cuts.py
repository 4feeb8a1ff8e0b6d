"""Whether a cut of the likelihood final stage's device work keeps its result
(``python -m core.studies.tracking.stage_cuts``): the stage's pose and covariance under each variant
against the default's, in units of the Cramér–Rao bound's σ.

The scene is :mod:`core.studies.tracking.stage_residue`'s kind (:class:`~core.studies.tracking.acceptance.
TrackingScene`, by default 256², 1 mm voxels, seed 0, the model's distortion correction), the frames the
noisy ones (the run's draw). Per bone and frame the stage runs as the tracker runs it
(:func:`~core.studies.tracking.stage_residue.stage_from`: its region about the start, the default model with
its robust round, the other bones at their true poses subtracted) from one start — the truth moved by
``start_sigmas`` × the bound's σ per axis, a normal draw of its own per bone-frame (the search's optimum is
about that far off: the stage's moves) — under each variant (:func:`core.studies.tracking.stage_one_bone.
_variant_of`'s names: ``stage_speed``'s variants, ``stride<n>``, ``chord``…). Against the first variant:
per bone the largest and the RMS difference of the poses over the bound's σ (per axis; ``pose_over_sigma``),
the covariance's σ as a ratio (the largest departure from 1 over the axes and frames; ``sigma_ratio``), the
steps; and per variant the error over the bound (RMS over the frames, mm and degrees). JSON on stdout
(``--out``: also to a file)."""

from __future__ import annotations

import time

import numpy as np

from core.studies.tracking import _study_cli as cli

__all__ = ["compare", "main", "run"]

#: the frames by default (every ninth of the first 100: ten frames a bone)
FRAMES = tuple(range(4, 100, 10))


def compare(base: list, other: list, sigma: np.ndarray) -> dict:
    """Two variants' rows of one bone (each ``{"error", "sigma", "steps"}``, the same frames) compared:
    their poses' difference over the bound's ``sigma`` (per axis; the error's difference is the poses'),
    the σ ratio other / base, and the mean steps."""
    E0 = np.array([r["error"] for r in base])
    E1 = np.array([r["error"] for r in other])
    D = (E1 - E0) / sigma
    S0 = np.array([r["sigma"] for r in base])
    S1 = np.array([r["sigma"] for r in other])
    R = S1 / np.where(S0 > 0, S0, np.nan)
    return {"pose_over_sigma_max": round(float(np.nanmax(np.abs(D))), 4),
            "pose_over_sigma_rms": np.sqrt(np.nanmean(D ** 2, axis=0)).round(4).tolist(),
            "sigma_ratio_max_departure": round(float(np.nanmax(np.abs(R - 1.0))), 4),
            "sigma_ratio_mean": np.nanmean(R, axis=0).round(4).tolist(),
            "steps_mean": [round(float(np.mean([r["steps"] for r in x])), 2) for x in (base, other)]}


def _over_bound(rows: list, bound: dict) -> list:
    E = np.array([r["error"] for r in rows])
    mm = float(np.sqrt(np.mean(np.sum(E[:, :3] ** 2, axis=1))))
    deg = float(np.sqrt(np.mean(np.sum(E[:, 3:] ** 2, axis=1))))
    return [round(mm / bound["rms_mm"], 3), round(deg / bound["rms_deg"], 3)]


def run(*, seed: int = 0, pixels: int = 256, voxel: float = 1.0, bones=("tibia", "talus", "calcaneus"),
        frames=FRAMES, variants=("base",), start_sigmas: float = 1.5, device: str | None = "cpu",
        ts=None, checkpoint=None) -> dict:
    """The study (module docs); returns the JSON-ready results. ``ts``: a scene of the caller's (tests)."""
    from core.studies.tracking.acceptance import TrackingScene, cramer_rao
    from core.studies.tracking.stage_one_bone import _variant_of
    from core.studies.tracking.stage_residue import _frames_of, stage_from
    from core.tracking.checks import step_pose

    t0 = time.perf_counter()
    if ts is None:
        ts = TrackingScene(n_frames=100, pixels=pixels, spacing=voxel, seed=seed, device=device,
                           phase=(0.0, 0.6))
    hp = 4.0 * pixels / 1024  # (the benchmark's 4 px at 1024², scaled)
    frames = tuple(int(f) for f in frames if f < ts.scene.n_frames)
    bound = cramer_rao(ts, frames)
    out = cli.header("core.studies.tracking.stage_cuts", seed=seed, pixels=pixels, voxel_mm=voxel,
                     highpass_px=hp, frames=list(frames), variants=list(variants), start_sigmas=start_sigmas)
    out["cramer_rao"] = bound
    rng = np.random.default_rng(seed + 1000)
    res: dict = {}
    for nm in bones:
        b = ts.names.index(nm)
        sig = np.asarray(bound[nm]["sigma"], dtype=float)
        c = ts.models[b].centroid
        rows: dict = {v: [] for v in variants}
        for f in frames:
            fr = _frames_of(ts, f, b, "noisy")
            dx = start_sigmas * sig * rng.standard_normal(6)  # (mm, degrees)
            P0 = step_pose(np.r_[dx[:3], np.radians(dx[3:])], ts.truth(f)[b], c)
            for v in variants:
                with _variant_of(v, [0, 0]):
                    r = stage_from(ts, fr, f, b, P0, highpass_px=hp)
                rows[v].append({k: r[k] for k in ("error", "sigma", "steps", "start")})
        first = variants[0]
        res[nm] = {"over_bound": {v: _over_bound(rows[v], bound[nm]) for v in variants},
                   "against_" + first: {v: compare(rows[first], rows[v], sig) for v in variants[1:]},
                   "rows": rows}
        out["bones"] = res
        out["seconds"] = round(time.perf_counter() - t0, 1)
        if checkpoint:
            checkpoint(out)
    return out


def main(argv=None) -> int:
    p = cli.parser("core.studies.tracking.stage_cuts", __doc__)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--pixels", type=int, default=256)
    p.add_argument("--voxel", type=float, default=1.0)
    p.add_argument("--bones", default="tibia,talus,calcaneus")
    p.add_argument("--frames", default=",".join(map(str, FRAMES)))
    p.add_argument("--variants", default="base")
    p.add_argument("--start-sigmas", type=float, default=1.5)
    p.add_argument("--device", default="cpu")
    cli.add_output(p)
    a = p.parse_args(argv)
    res = run(seed=a.seed, pixels=a.pixels, voxel=a.voxel, bones=tuple(cli.names(a.bones)),
              frames=tuple(cli.ints(a.frames)), variants=tuple(cli.names(a.variants)),
              start_sigmas=a.start_sigmas, device=a.device, checkpoint=cli.checkpoint(a))
    return cli.finish(res, a)


if __name__ == "__main__":
    raise SystemExit(main())
