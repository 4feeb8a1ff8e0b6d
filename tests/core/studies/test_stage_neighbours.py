"""core.studies.tracking.stage_neighbours: the stage's neighbours replaced by their searched poses,
the wrapper put back, the stage log's errors (no rendering)."""

from types import SimpleNamespace

import numpy as np
import pytest

from core.studies.tracking import stage_neighbours as sn


def _pose(t: float) -> np.ndarray:
    P = np.eye(4)
    P[:3, 3] = t
    return P


def test_searched_others_replaces_the_staged_neighbours_only():
    pred = {0: _pose(1.0), 1: _pose(2.0), 2: _pose(3.0)}
    found = {0: _pose(10.0), 1: _pose(20.0)}  # bone 2 not staged here (its search fell back)
    calls = [(SimpleNamespace(pose=found[b]), {"bone": b, "others": (np.stack([pred[k] for k in ids]), ids)})
             for b, ids in ((0, [1, 2]), (1, [0, 2]))]
    new = sn.searched_others(calls)
    (P0, ids0), (P1, ids1) = new[0][1]["others"], new[1][1]["others"]
    assert ids0 == [1, 2] and ids1 == [0, 2]
    np.testing.assert_array_equal(P0[0], found[1])
    np.testing.assert_array_equal(P0[1], pred[2])  # kept: not one of the calls' bones
    np.testing.assert_array_equal(P1[0], found[0])
    assert new[0][0] is calls[0][0] and calls[0][1]["others"][0][0][0, 3] == 2.0  # the input untouched
    alone = [(SimpleNamespace(pose=_pose(0)), {"bone": 0, "others": None})]
    assert sn.searched_others(alone)[0][1]["others"] is None


def test_the_wrapper_is_put_back():
    import core.tracking.final_stage as fst
    import core.tracking.trial as trial

    plain = fst.final_stages, trial.track_frame
    with pytest.raises(RuntimeError), sn.stage_neighbours_at(True, []):
        assert fst.final_stages is not plain[0] and trial.track_frame is not plain[1]
        raise RuntimeError
    assert (fst.final_stages, trial.track_frame) == plain


def test_stage_rows_and_summary():
    # a stand-in scene: the truth at the identity, each bone's centroid at the origin
    ts = SimpleNamespace(names=("tibia", "talus", "calcaneus"), truth=lambda f: np.stack([np.eye(4)] * 3),
                         models=[SimpleNamespace(centroid=np.zeros(3))] * 3)
    log = [{"frame": 5, "bone": 2, "searched": _pose(0.1), "n_calls": 2,
            "neighbours_searched": {1: _pose(0.2)},
            "others": (np.stack([_pose(0.3), _pose(0.4)]), [0, 1])}]
    (row,) = sn._stage_rows(ts, log)
    assert row["bone"] == "calcaneus" and row["searched"][:3] == [0.1] * 3
    assert row["neighbours"]["tibia"]["searched"] is None and row["neighbours"]["talus"]["searched"][0] == 0.2
    assert row["neighbours"]["talus"]["subtracted"][:3] == [0.4] * 3
    s = sn.neighbour_summary({"stages": {"joint": [row]}})
    assert s["calcaneus<-tibia"]["searched"] is None
    np.testing.assert_allclose(s["calcaneus<-talus"]["subtracted"], [0.4 * 3 ** 0.5, 0.0], atol=1e-4)
    np.testing.assert_allclose(s["calcaneus<-talus"]["searched"], [0.2 * 3 ** 0.5, 0.0], atol=1e-4)
