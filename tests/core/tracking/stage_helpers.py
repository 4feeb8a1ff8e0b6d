"""The likelihood final stages' calls of a joint registration on the ideal 128² talus-calcaneus scene
(the ``talus_calcaneus_128`` fixture, frame 1: both bones started off the truth, each with the other at
its true pose subtracted), shared by the side-by-side stages' tests and the recorded steps' tests; the
talus's noisy frame 3 and its start off the truth (:func:`noisy_start`) and an engine set on frame 2 at
the truth (:func:`engine_at`), shared by the stage's tests on the ``talus_scene`` fixture."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from core.geometry.transforms import pose_from_params

__all__ = ["engine_at", "noisy_start", "stage_calls"]


def stage_calls(talus_calcaneus_128) -> tuple:
    """``(renderer, frame, calls, options)``: the frame prepared, per bone ``(registration result,
    final_stage kwargs)`` with the stage at a 2 px high-pass, and the stage's registration options."""
    from core.tracking.cost import prepare_frame
    from core.tracking.joint import JointJob, register_together
    from core.tracking.register import RegistrationOptions

    sc, models, r, frames = talus_calcaneus_128
    frame = prepare_frame(frames[1])
    o = RegistrationOptions(bounds=(5.0, 5.0), sigma=(1.0, 1.0), search="newton")
    truth = sc.poses(1)
    offs = [np.r_[0.6, -0.4, 0.3, np.radians([0.8, -0.5, 0.6])],
            np.r_[-0.5, 0.3, 0.4, np.radians([-0.6, 0.7, 0.4])]]
    jobs = [JointJob(k, pose_from_params(d, center=m.centroid, base=truth[k]), m.centroid, m.outline,
                     (truth[[1 - k]], [1 - k])) for k, (d, m) in enumerate(zip(offs, models, strict=True))]
    regs = register_together(r, frame, jobs, o)
    of = replace(o, final="likelihood", final_highpass_px=2.0)
    calls = [(regs[k], {"bone": k, "initial_pose": job.initial_pose, "center": job.center, "options": of,
                        "views": (0, 1), "others": job.others}) for k, job in enumerate(jobs)]
    return r, frame, calls, of


def noisy_start(talus_scene) -> tuple:
    """``(frame, start, options)``: the talus's frame 3 with 1 % multiplicative noise (seed 4), a start
    0.3/0.2/-0.2 mm off its true pose, registration options with the stage at a 2 px high-pass."""
    from core.tracking.cost import prepare_frame
    from core.tracking.register import RegistrationOptions

    sc = talus_scene["scene"]
    g = np.random.default_rng(4)
    fl = [np.clip(f * (1.0 + 0.01 * g.normal(size=f.shape)), 0.0, 1.0).astype(np.float32)
          for f in talus_scene["fluence"](3)]
    start = sc.poses(3)[0].copy()
    start[:3, 3] += (0.3, 0.2, -0.2)
    o = RegistrationOptions(bounds=(3.0, 3.0), search="newton", final="likelihood", final_highpass_px=2.0)
    return prepare_frame(fl, valid_range=None), start, o


def engine_at(talus_scene, frame: int = 2):
    """A :class:`~core.tracking.engine_likelihood.LikelihoodEngine` of the talus (2 px high-pass, both
    views) set on ``frame`` at its true pose, the search region 2 mm about it."""
    import core.tracking.engine_likelihood as el
    from core.tracking.cost import prepare_frame, search_roi

    sc, model, r = talus_scene["scene"], talus_scene["model"], talus_scene["renderer"]
    start = sc.poses(frame)[0]
    fr = prepare_frame(talus_scene["fluence"](frame), valid_range=None)
    roi = search_roi(r, start, 0, views=[0, 1], center=model.centroid, reach_mm=2.0)
    eng = el.LikelihoodEngine(r, bone=0, views=(0, 1), highpass_px=2.0)
    eng.set_frame(fr, base_pose=start, center=model.centroid, roi=roi)
    return eng
