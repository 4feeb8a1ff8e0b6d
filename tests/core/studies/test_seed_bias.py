"""core.studies.tracking.seed_bias on a tiny scene: its frames, rim figures and conditions."""

import json

import numpy as np
import pytest

from core.studies.tracking import seed_bias as sb


@pytest.fixture(scope="module")
def scene():
    from core.studies.tracking.acceptance import TrackingScene

    return TrackingScene(n_frames=3, pixels=64, spacing=2.0, seed=4, device="cpu", correction="exact",
                         phase=(0.0, 0.018))


def test_frames_without_the_other_bones(scene):
    f, b = 1, scene.names.index("talus")
    L = scene.scene.line_integrals(f, renderer=scene._scene_renderer)
    alone = sb._without(scene, f, L, b)
    gone = L - alone
    assert gone.min() >= -1e-4 and gone.max() > 0.5  # the tibia's and calcaneus' integrals, taken out
    R = scene._scene_renderer._bones.render(scene.truth(f)[None], roi="full").numpy()[0]
    np.testing.assert_allclose(gone, R[:, [0, 2]].sum(axis=1), atol=1e-3)
    # noise-free frames are deterministic, noisy ones the run's draw (the scene's own frames)
    a, c = sb._chain(scene, f, L, False), sb._chain(scene, f, L, False)
    np.testing.assert_array_equal(a[0], c[0])
    np.testing.assert_allclose(sb._chain(scene, f, L, True)[1], scene.frames(f)[1], atol=1e-6)


def test_field_rim(scene):
    rim = sb.field_rim(scene, 0, scene.names.index("tibia"))
    assert len(rim) == 2
    for v in rim:
        assert 0.0 < v["max_r"] < 2.0 and 0.0 <= v["beyond_0.9"] <= 1.0


def test_run_and_summary(scene, tmp_path):
    stored = tmp_path / "run.json"
    stored.write_text(json.dumps({"tracking": {"talus": {"per_frame_error": np.zeros((3, 6)).tolist()}}}))
    out = sb.run(ts=scene, frames={"talus": (1,)}, conditions=("noisy", "from_run"), stored=str(stored))
    (row,) = out["rows"]
    assert row["bone"] == "talus" and row["run"] == [0.0] * 6
    # from the stored run's pose, here the truth: the same start as "noisy", so the same result
    np.testing.assert_allclose(row["from_run"], row["noisy"], atol=2e-3)
    assert out["summary"]["talus"]["noisy"]["n"] == 1
    assert set(out["cramer_rao"]) == {"tibia", "talus", "calcaneus"}


def test_stage_run_and_summary(scene):
    out = sb.stage_run(ts=scene, frames={"talus": (1,)}, draws=(None, 1),
                       variants=("gc", "hp4", "hp8"))
    assert [r["draw"] for r in out["rows"]] == [None, 1]
    for r in out["rows"]:
        assert {"gc", "hp4", "hp8"} <= set(r) and len(r["hp4"]) == 6
        assert r["hp4_taken"] in (0, 1)
    assert out["highpass_px"] == {"hp4": 4.0 * 64 / 1024, "hp8": 8.0 * 64 / 1024}
    s = out["summary"]["talus"]
    assert s["noise_free"]["hp4"]["stretch"]["n"] == 1 and s["noisy"]["gc"]["stretch"]["n"] == 1  # (frame 1)
    # another noise draw differs from the run's own
    L = scene.scene.line_integrals(1, renderer=scene._scene_renderer)
    assert not np.array_equal(sb._draw(scene, 1, L, 1)[0], sb._draw(scene, 1, L, 0)[0])


def test_stored_errors_are_by_frame_number(tmp_path):
    """A stored run's per-frame errors are placed by frames_with_pose: a frame without a pose (2)
    shifts the later errors' positions, not their frames."""
    E = [[0.1 * k] * 6 for k in (0, 1, 3, 4)]
    run = {"config": {"frames": 5},
           "tracking": {"talus": {"per_frame_error": E, "frames_with_pose": [0, 1, 3, 4]}}}
    p = tmp_path / "run.json"
    p.write_text(json.dumps({"runs": {"joint": run}}))
    got = sb._stored_errors(str(p), "joint")["talus"]
    assert sorted(got) == [0, 1, 3, 4]
    np.testing.assert_allclose(got[3], [0.3] * 6)
    assert sb._stored_errors(None, "joint") == {}
    # without frames_with_pose, the errors are frames 0..n-1 only when every frame has one
    del run["tracking"]["talus"]["frames_with_pose"]
    p.write_text(json.dumps(run))
    with pytest.raises(ValueError, match="name no frames"):
        sb._stored_errors(str(p), "joint")
    run["config"]["frames"] = 4
    p.write_text(json.dumps(run))
    np.testing.assert_allclose(sb._stored_errors(str(p), "joint")["talus"][3], [0.4] * 6)
