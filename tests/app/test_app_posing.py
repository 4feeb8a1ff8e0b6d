"""Qt-free viewer model and posing math: no display needed."""

import numpy as np
import pytest

from app.model import ViewerModel
from app.posing import drag_angle, nudge, rotate_in_view, translate_in_view
from core.render import CTVolume
from core.synthetic import foot_rig


@pytest.fixture(scope="module")
def rig():
    return foot_rig(pixels=128, seed=1)


def _volume():
    data = np.full((10, 12, 14), -1000, np.int16)
    data[2:8, 3:9, 4:10] = 1200
    return CTVolume(data, spacing=[1.0, 1.0, 1.5], origin=[-7.0, -6.0, -7.0], name="cube")


def test_translate_in_view_moves_projection_exactly_and_the_other_view_consistently(rig):
    vol = _volume()
    c_b = vol.centroid()
    T = np.eye(4)
    T[:3, 3] = [3.0, -2.0, 5.0]
    c0 = T[:3, :3] @ c_b + T[:3, 3]
    uv0 = rig.project(c0)
    T2 = translate_in_view(rig[0], T, c_b, 12.5, -7.0)
    c1 = T2[:3, :3] @ c_b + T2[:3, 3]
    uv1 = rig.project(c1)
    np.testing.assert_allclose(uv1[0] - uv0[0], [12.5, -7.0], atol=1e-9)
    # depth along camera 0 unchanged; the move is parallel to its detector plane
    assert abs(rig[0].principal_ray @ (c1 - c0)) < 1e-9
    # the second view sees the same 3D displacement (as its camera model predicts)
    np.testing.assert_allclose(uv1[1], rig[1].project(c0 + (c1 - c0)), atol=1e-9)
    assert np.linalg.norm(uv1[1] - uv0[1]) > 1.0
    np.testing.assert_allclose(T2[:3, :3], T[:3, :3])


def test_rotate_in_view_keeps_the_projected_centroid_and_turns_clockwise(rig):
    vol = _volume()
    c_b = vol.centroid()
    T = np.eye(4)
    cam = rig[1]
    T2 = rotate_in_view(cam, T, c_b, np.deg2rad(10))
    c = T[:3, :3] @ c_b + T[:3, 3]
    np.testing.assert_allclose(cam.project(T2[:3, :3] @ c_b + T2[:3, 3]), cam.project(c), atol=1e-9)
    # a point off the centroid turns ~10 degrees clockwise on screen (v down) around it
    p_b = c_b + np.array([5.0, 0.0, 0.0])
    uc = cam.project(c)
    a = cam.project(T[:3, :3] @ p_b + T[:3, 3])
    b = cam.project(T2[:3, :3] @ p_b + T2[:3, 3])
    assert np.rad2deg(drag_angle(uc, a, b)) == pytest.approx(10.0, abs=0.5)
    assert drag_angle([0, 0], [1, 0], [0, 1]) == pytest.approx(np.pi / 2)  # (1,0)->(0,1): clockwise


def test_nudge_rotates_about_the_centroid():
    c_b = np.array([1.0, 2.0, 3.0])
    T = np.eye(4)
    T2 = nudge(T, c_b, translate=[1, 0, 0], rotate=[0, 0, np.pi / 2])
    np.testing.assert_allclose(T2[:3, :3] @ c_b + T2[:3, 3], c_b + np.array([1.0, 0, 0]), atol=1e-12)


def test_model_undo_redo_merge_and_events(rig):
    m = ViewerModel(rig, n_frames=5)
    seen = []
    m.pose_changed.connect(lambda b, f: seen.append((b, f)))
    i = m.add_bone("cube", _volume())
    assert m.selected == i
    T1, T2, T3 = (np.eye(4) for _ in range(3))
    T1[0, 3], T2[0, 3], T3[0, 3] = 1.0, 2.0, 3.0
    m.set_pose("cube", T1, merge="drag")
    m.set_pose("cube", T2, merge="drag")  # same drag: one undo step
    m.end_interaction()
    m.set_pose("cube", T3)
    assert seen == [(0, 0)] * 3 and m.dirty
    m.undo()
    np.testing.assert_array_equal(m.pose("cube"), T2)
    m.undo()
    np.testing.assert_array_equal(m.pose("cube"), np.eye(4))
    assert not m.can_undo and m.can_redo
    m.redo()
    np.testing.assert_array_equal(m.pose("cube"), T2)
    m.set_frame(3)
    np.testing.assert_array_equal(m.pose("cube"), np.eye(4))  # poses are per frame
    assert 0 in m.layers[0].keyframes


def test_model_rejects_bad_edits(rig):
    m = ViewerModel(rig, n_frames=2)
    m.add_bone("cube", _volume())
    with pytest.raises(ValueError, match="rigid"):
        m.set_pose("cube", np.diag([2.0, 1, 1, 1]))
    with pytest.raises(ValueError, match="no bone named"):
        m.pose("talus")
    m.set_layer_property("cube", "locked", True)
    with pytest.raises(ValueError, match="locked"):
        m.set_pose("cube", np.eye(4))
    with pytest.raises(ValueError, match="already"):
        m.add_bone("cube", _volume())
    with pytest.raises(ValueError, match="opacity"):
        m.set_layer_property("cube", "opacity", 2.0)
