"""tissue_stage: the final stage's tissue model as the study gives it (the user's volumes through
the scene's transfer, each following its bone), and the summary table."""

from types import SimpleNamespace

import numpy as np

from core.render import CTVolume, HUTransfer
from core.studies.tracking import tissue_stage as tst
from core.tracking.final_stage import FinalModel


def _ts():
    z, y, x = np.mgrid[0:12, 0:10, 0:14]
    blob = ((x - 6.5) / 5) ** 2 + ((y - 4.5) / 4) ** 2 + ((z - 5.5) / 5) ** 2 < 1
    vols = tuple(CTVolume((-1000 + 1040 * blob).astype(np.float32), spacing=np.full(3, 3.0),
                          origin=np.array([-20.0, -15.0, -17.0]), name=nm)
                 for nm in ("soft_foot", "soft_shank"))
    scene = SimpleNamespace(tissue=vols, tissue_bones=(2, 0), tissue_transfer=HUTransfer())
    return SimpleNamespace(scene=scene)


def test_tissue_model_follows_the_scenes_bones():
    m = tst.tissue_model(_ts(), psf=False, each=True, base=FinalModel(robust=None))
    assert [b for _, b in m.tissue] == [2, 0] and m.tissue_each and m.tissue_psf is None and m.robust is None
    for v, _ in m.tissue:
        assert v.units == "1/mm" and np.allclose(v.spacing, 4.0) and v.data.max() > 0
    d = m.to_dict()
    assert [t["bone"] for t in d["tissue"]] == [2, 0] and d["tissue_psf"] is None


def test_table_lines():
    s = {"over_bound": {"mm": 1.2, "deg": 1.1}, "over_4x_bound": {"over": 1, "silent": 0}}
    res = {"three": {"mode": "joint", "hp4_tissue": {"track_s": 1.0, "likelihood_ms_per_bone_frame": 20.0,
                                                       "tibia": s, "talus": s, "calcaneus": s}}}
    (line,) = tst.table(res)
    assert line.startswith("three hp4_tissue: tibia 1.20/1.10 (>4x 1, silent 0)") and "20.0 ms" in line
