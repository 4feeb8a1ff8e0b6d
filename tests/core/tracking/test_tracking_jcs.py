"""core.tracking.jcs against ground truth: JCS angles and translations recovered from composed
poses, helical axes of known screw motions, default joints and anatomical frames."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from core.tracking.jcs import Joint, anatomical_frames, compose_jcs, default_joints, jcs_rms, joint_series


def _rigid(rng, t_scale=50.0):
    T = np.eye(4)
    T[:3, :3] = Rotation.random(random_state=rng).as_matrix()
    T[:3, 3] = rng.normal(scale=t_scale, size=3)
    return T


@pytest.mark.parametrize("axes", [("x", "z"), ("z", "y"), ("y", "x")])
def test_angles_and_translations_recovered(axes):
    rng = np.random.default_rng(3)
    joint = Joint("j", "a", "b", *axes)
    n = 25
    truth_a = np.column_stack([rng.uniform(-60, 60, n), rng.uniform(-40, 40, n), rng.uniform(-70, 70, n)])
    truth_t = rng.normal(scale=5.0, size=(n, 3))
    Fa, Fb = _rigid(rng, 10), _rigid(rng, 10)  # T_bone_from_anatomical
    Pa = np.stack([_rigid(rng) for _ in range(n)])
    Pb = np.stack([Pa[k] @ Fa @ compose_jcs(truth_a[k], truth_t[k], e1_axis=axes[0], e3_axis=axes[1])
                   @ np.linalg.inv(Fb) for k in range(n)])
    out = joint_series({"a": Pa, "b": Pb}, joint, {"a": Fa, "b": Fb})
    np.testing.assert_allclose(out["angles_deg"], truth_a, atol=1e-8)
    np.testing.assert_allclose(out["translations_mm"], truth_t, atol=1e-8)
    assert out["sequence"][0] == axes[0].upper() and out["sequence"][2] == axes[1].upper()


def test_compose_is_the_grood_suntay_construction():
    # e1 stays the proximal axis; e3 is the distal axis; the floating axis is perpendicular to both
    T = compose_jcs([20.0, -15.0, 35.0], e1_axis="x", e3_axis="z")
    e1, e3 = np.array([1.0, 0, 0]), T[:3, 2]
    e2 = np.cross(e3, e1)
    e2 /= np.linalg.norm(e2)
    # the flexion angle is the angle of e2 from the proximal y axis, about e1
    assert np.rad2deg(np.arctan2(e2[2], e2[1])) == pytest.approx(20.0)
    # the ab/adduction angle is 90 degrees minus the angle between e1 and e3
    assert np.rad2deg(np.arccos(e1 @ e3)) == pytest.approx(90.0 + 15.0)


def test_helical_axis_of_a_known_screw():
    rng = np.random.default_rng(5)
    n = 8
    axis = np.array([1.0, 2.0, -0.5]) / np.linalg.norm([1.0, 2.0, -0.5])
    point = np.array([3.0, -4.0, 10.0])
    angle_step, slide_step = 4.0, 0.7  # deg, mm per frame
    Pa = np.stack([_rigid(rng) for _ in range(n)])
    rel = []
    for k in range(n):
        R = Rotation.from_rotvec(axis * np.deg2rad(angle_step * k)).as_matrix()
        T = np.eye(4)
        T[:3, :3] = R
        T[:3, 3] = point - R @ point + axis * slide_step * k
        rel.append(T)
    Pb = np.stack([Pa[k] @ rel[k] for k in range(n)])
    out = joint_series({"a": Pa, "b": Pb}, Joint("j", "a", "b"))
    assert np.isnan(out["helical_angle_deg"][0])
    np.testing.assert_allclose(out["helical_angle_deg"][1:], angle_step, atol=1e-8)
    np.testing.assert_allclose(out["helical_translation_mm"][1:], slide_step, atol=1e-8)


def test_missing_frames_are_nan_and_rms():
    rng = np.random.default_rng(1)
    n = 6
    Pa = np.stack([_rigid(rng) for _ in range(n)])
    Pb = np.stack([Pa[k] @ compose_jcs([10.0 * k, 5.0, -3.0]) for k in range(n)])
    Pb_off = np.stack([Pa[k] @ compose_jcs([10.0 * k + 0.5, 5.0, -3.0]) for k in range(n)])
    Pb[2] = np.nan
    j = Joint("j", "a", "b")
    out = joint_series({"a": Pa, "b": Pb}, j)
    assert np.isnan(out["angles_deg"][2]).all() and np.isnan(out["helical_angle_deg"][[2, 3]]).all()
    r = jcs_rms({"a": Pa, "b": Pb}, {"a": Pa, "b": Pb_off}, [j])["j"]
    assert r["frames"] == n - 1
    np.testing.assert_allclose(r["rms_deg"], [0.5, 0.0, 0.0], atol=1e-8)


def test_default_joints():
    assert [(j.name, j.proximal, j.distal) for j in default_joints(["tibia", "talus", "calcaneus"])] == [
        ("ankle", "tibia", "talus"), ("subtalar", "talus", "calcaneus")]
    assert [(j.proximal, j.distal) for j in default_joints(["radius", "scaphoid", "lunate"])] == [
        ("radius", "scaphoid"), ("scaphoid", "lunate")]
    assert default_joints(["talus"]) == []


def test_anatomical_frames_principal_axes_and_given():
    rng = np.random.default_rng(2)
    pts = rng.normal(size=(4000, 3)) * [2.0, 10.0, 5.0] + [1.0, 2.0, 3.0]  # long axis along y
    given = np.eye(4)
    given[:3, 3] = [1, 1, 1]
    fr = anatomical_frames({"a": pts, "b": pts}, given={"b": given})
    T = fr["a"]
    assert abs(T[:3, 2] @ [0, 1, 0]) > 0.99  # longest extent on the frame's z
    assert abs(T[:3, 0] @ [0, 0, 1]) > 0.99  # second longest on x
    np.testing.assert_allclose(T[:3, 3], [1, 2, 3], atol=0.5)
    np.testing.assert_allclose(fr["b"], given)
    with pytest.raises(ValueError, match="given\\['b'\\]"):
        anatomical_frames({"b": pts}, given={"b": np.ones((4, 4))})


def test_errors_name_the_argument():
    with pytest.raises(ValueError, match="e1_axis"):
        Joint("j", "a", "b", "x", "x")
    with pytest.raises(ValueError, match="needs bone 'b'"):
        joint_series({"a": np.zeros((2, 4, 4))}, Joint("j", "a", "b"))
