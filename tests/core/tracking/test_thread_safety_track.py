"""One registering thread per device (core.tracking.trial.device_lock): a second tracking on the same device
in another thread waits for the first, and the two give the poses of the same two one after the other (Warp's
CPU device, a small scene: the first frame's search and one tracked frame)."""

from __future__ import annotations

import threading
from dataclasses import replace

import numpy as np


def test_device_lock_is_per_device_and_reentrant():
    from core.tracking.trial import device_lock

    a = device_lock("cpu")
    assert device_lock("cpu") is a and device_lock("cuda:0") is not a
    with a, a:  # (re-entrant: a tracking in a tracking's callback on the same thread)
        pass


def test_second_tracking_on_the_device_waits_for_the_first():
    from core.render import DRRRenderer
    from core.studies.tracking.acceptance import TrackingScene
    from core.studies.tracking.trial_frames import synthesise
    from core.tracking.trial import TrackingOptions, track

    ts = TrackingScene(n_frames=2, pixels=24, spacing=5.0, phase=(0.0, 0.012), device="cpu")
    synthesise(ts, range(2), 0)
    model = ts.models[1]
    kf = {model.name: {0: ts.truth(0)[1], 1: ts.truth(1)[1]}}
    o = replace(TrackingOptions(mode="joint"), refine_likelihood=True)

    def renderer():
        vol = model.volume.to_attenuation(ts.scene.bone_transfer)
        return DRRRenderer(ts.scene.rig, [vol], device=ts.device)

    def poses(res):  # (each frame's pose, flags and notes)
        return {k: (np.asarray(r.pose), tuple(r.flags), tuple(r.notes)) for k, r in res.results.items()}

    def same(x, y):
        return x.keys() == y.keys() and all(
            np.array_equal(x[k][0], y[k][0]) and x[k][1:] == y[k][1:] for k in x)

    ref = poses(track(renderer(), [model], ts.frames, [0, 1], keyframes=kf, options=o))
    first_in, go_on, second_read = threading.Event(), threading.Event(), threading.Event()
    got, errors = {}, []

    def held(done, total, fr):  # the first run stays inside its run until told
        first_in.set()
        go_on.wait(30)

    def frames_b(f):
        second_read.set()
        return ts.frames(f)

    def one(key, frames, progress):
        try:
            got[key] = poses(track(renderer(), [model], frames, [0, 1], keyframes=kf, options=o,
                                   progress=progress))
        except Exception as e:  # (reported below)
            errors.append(repr(e))

    a = threading.Thread(target=one, args=("a", ts.frames, held))
    a.start()
    assert first_in.wait(60)
    b = threading.Thread(target=one, args=("b", frames_b, None))
    b.start()
    waited = not second_read.wait(0.5)  # the second has not read a frame: it waits at the device's lock
    go_on.set()
    a.join(120)
    b.join(120)
    assert waited and not errors, errors
    assert second_read.is_set()
    assert len(ref) == 2 and same(got["a"], ref) and same(got["b"], ref)
