"""The likelihood engine's recorded launches taken without building their key where the arguments are the
last call's objects (likelihood_launches.SAME_OBJECTS): the same tables to the bit as with the key built at
every launch; a new array (another address) or another number records the launch again."""

from __future__ import annotations

import numpy as np
import warp as wp

from tests.core.tracking.stage_helpers import engine_at


def test_same_objects_give_the_same_tables(talus_scene, monkeypatch):
    import core.tracking.engine_likelihood as el
    import core.tracking.likelihood_launches as ll

    monkeypatch.setattr(el, "STEP_GRAPH", False)  # (every step's kernels through _launch)
    eng = engine_at(talus_scene)
    x, h = np.array([0.05, -0.1, 0.0, 0.1, 0.0, -0.05]), np.full(6, 0.05)
    tables = []
    for on in (False, True, True):
        monkeypatch.setattr(ll, "SAME_OBJECTS", on)
        tables.append(eng.step(x, h)["M"].copy())
    for t in tables[1:]:
        np.testing.assert_array_equal(tables[0], t)


def test_other_arguments_record_again(talus_scene):
    eng = engine_at(talus_scene)
    a = wp.zeros(8, dtype=wp.float32, device=eng.device)

    @wp.kernel
    def fill(out: wp.array(dtype=wp.float32), v: float):
        out[wp.tid()] = v

    eng._launch("t", fill, (8,), [a, 1.0])
    cmd = eng._cmds["t"][1]
    eng._launch("t", fill, (8,), [a, 1.0])
    assert eng._cmds["t"][1] is cmd
    eng._launch("t", fill, (8,), [a, 2.0])
    assert eng._cmds["t"][1] is not cmd and np.all(a.numpy() == 2.0)
    b = wp.zeros(8, dtype=wp.float32, device=eng.device)
    eng._launch("t", fill, (8,), [b, 2.0])
    assert np.all(b.numpy() == 2.0)
