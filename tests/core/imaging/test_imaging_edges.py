"""Edge operators of thesis §6.4 (core.imaging.edges)."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import ndimage

from core.imaging.edges import (
    FIRST_DERIVATIVE_OPERATORS,
    OPERATORS,
    derivative_kernels,
    detect_edges,
    frei_chen_basis,
    gradient,
    operator_kernels,
)

V, U = np.mgrid[0:24, 0:24].astype(float)


def _sigma(op):
    return 1.5 if op == "gaussian" else 0.0


def test_printed_kernels_have_zero_sum_and_thesis_scaling():
    for op in OPERATORS:
        if op == "gaussian":
            with pytest.raises(ValueError, match="sigma"):
                operator_kernels(op)
            continue
        for name, k in operator_kernels(op).items():
            if name != "G9":
                assert abs(k.sum()) < 1e-12, (op, name)
    ab = operator_kernels("abdou")
    assert ab["rows"].shape == (7, 7)
    assert ab["rows"][ab["rows"] > 0].sum() == pytest.approx(1.0)  # 1/34 normalises each half
    assert operator_kernels("sobel")["rows"][1, 0] == pytest.approx(0.5)


def test_frei_chen_basis_is_orthonormal():
    b = frei_chen_basis().reshape(9, 9)
    np.testing.assert_allclose(b @ b.T, np.eye(9), atol=1e-12)


@settings(max_examples=25, deadline=None)
@given(theta=st.floats(-np.pi, np.pi), slope=st.floats(0.1, 5.0))
def test_normalised_gradient_of_a_ramp_is_exact_for_every_operator(theta, slope):
    img = slope * (np.cos(theta) * U + np.sin(theta) * V)
    for op in FIRST_DERIVATIVE_OPERATORS:
        gu, gv = gradient(img, operator=op, sigma=_sigma(op))
        inner = (slice(8, 16), slice(8, 16))
        np.testing.assert_allclose(gu[inner], slope * np.cos(theta), atol=1e-6 * slope, err_msg=op)
        np.testing.assert_allclose(gv[inner], slope * np.sin(theta), atol=1e-6 * slope, err_msg=op)
        em = detect_edges(img, op, sigma=_sigma(op))  # printed scaling: orientation still agrees
        d = np.abs(em.orientation[inner] - np.mod(theta, np.pi))
        assert np.all(np.minimum(d, np.pi - d) < 1e-6), op


def test_orientation_is_modulo_pi_and_magnitude_is_eq_6_14():
    rng = np.random.default_rng(1)
    img = ndimage.gaussian_filter(rng.random((32, 32)), 2)
    for op in ("sobel", "prewitt", "abdou", "roberts", "frei_chen", "separated_central_difference"):
        a, b = detect_edges(img, op), detect_edges(-img, op)
        np.testing.assert_allclose(a.orientation, b.orientation, atol=1e-9)
        assert np.all((a.orientation >= 0) & (a.orientation < np.pi))
        np.testing.assert_allclose(a.magnitude, b.magnitude)
        if op != "frei_chen":
            np.testing.assert_allclose(a.magnitude, np.abs(a.responses).mean(axis=0))
            e = detect_edges(img, op, magnitude="euclidean")
            np.testing.assert_allclose(e.magnitude, np.sqrt((a.responses**2).sum(axis=0)))


def test_step_edge_magnitude_peaks_on_the_edge():
    img = (U >= 12).astype(float)
    for op in OPERATORS:
        m = detect_edges(img, op, sigma=_sigma(op)).magnitude[12]
        peak = int(np.argmax(m))
        assert peak in (11, 12), (op, peak)
        assert m[2] == pytest.approx(0.0, abs=1e-12) and m[21] == pytest.approx(0.0, abs=1e-12)


def test_laplacian_line_orientation_is_the_line_normal_and_point_has_none():
    cases = {0.0: np.abs(U - 12) < 0.5, np.pi / 2: np.abs(V - 12) < 0.5,
             np.pi / 4: np.abs(U + V - 24) < 0.5, 3 * np.pi / 4: np.abs(U - V) < 0.5}
    for normal, line in cases.items():
        em = detect_edges(line.astype(float), "laplacian_line")
        assert em.orientation[12, 12] == pytest.approx(normal)
        assert len(em.responses) == 4
    assert np.all(np.isnan(detect_edges(U, "laplacian_point").orientation))


def test_frei_chen_feature_weights_separate_edges_from_lines():
    b = frei_chen_basis()
    edge = np.tile(b[1], (1, 1))  # a pure G2 patch
    line = b[4]
    e_edge = detect_edges(np.pad(edge, 4, mode="edge"), "frei_chen")
    e_line = detect_edges(np.pad(line, 4, mode="constant"), "frei_chen")
    assert e_edge.feature[5, 5] == pytest.approx(1.0)
    assert e_line.feature[5, 5] == pytest.approx(0.0, abs=1e-12)
    lines = detect_edges(np.pad(line, 4, mode="constant"), "frei_chen", weights=[0, 0, 0, 0, 1, 1, 1, 1, 0])
    assert lines.feature[5, 5] == pytest.approx(1.0)


def test_presmoothing_lowers_the_noise_response():
    rng = np.random.default_rng(2)
    noise = rng.normal(0, 1, (64, 64))
    raw = detect_edges(noise, "sobel").magnitude.std()
    smooth = detect_edges(noise, "sobel", sigma=1.5).magnitude.std()
    assert smooth < 0.3 * raw


def test_derivative_kernels_are_3x3_except_abdou():
    for op in FIRST_DERIVATIVE_OPERATORS:
        if op == "gaussian":
            with pytest.raises(ValueError):
                derivative_kernels(op)
            continue
        ku, kv = derivative_kernels(op)
        assert ku.shape == kv.shape == ((7, 7) if op == "abdou" else (3, 3))


def test_bad_input_is_rejected_with_the_argument_named():
    with pytest.raises(ValueError, match="operator"):
        detect_edges(U, "canny")
    with pytest.raises(ValueError, match="image"):
        detect_edges(np.zeros((3, 3, 3)), "sobel")
    with pytest.raises(ValueError, match="image"):
        detect_edges(np.full((4, 4), np.nan), "sobel")
    with pytest.raises(ValueError, match="sigma"):
        detect_edges(U, "gaussian")
    with pytest.raises(ValueError, match="weights"):
        detect_edges(U, "sobel", weights=np.ones(9))
    with pytest.raises(ValueError, match="magnitude"):
        detect_edges(U, "sobel", magnitude="max")
    with pytest.raises(ValueError, match="operator"):
        gradient(U, operator="laplacian_point")
