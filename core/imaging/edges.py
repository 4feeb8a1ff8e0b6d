"""Edge operators of thesis §6.4: directional responses, magnitude (6.14) and orientation (6.15).

Operators (3 × 3 unless noted; kernels as printed in the thesis, :func:`operator_kernels`)
------------------------------------------------------------------------------------------
``central_difference``, ``separated_central_difference``, ``roberts`` (diagonal pair),
``prewitt``, ``sobel``, ``abdou`` (7 × 7 truncated pyramid) — pairs of first-derivative kernels;
``laplacian_point`` (one kernel), ``laplacian_line`` (four line kernels: vertical, horizontal and
two diagonals), ``frei_chen`` (the nine orthonormal Frei–Chen basis masks, combined with feature
weights), and ``gaussian`` (derivative of a Gaussian of ``sigma`` pixels).

Conventions
-----------
* Images are indexed ``[row, col]``; pixel ``(u, v) = (col, row)``. Responses are
  *correlations* of the image with the kernels (borders replicate the edge pixels).
* First-derivative pairs are oriented the same way for every operator: ``E_u > 0`` where the
  intensity increases with ``u`` (to the right) and ``E_v > 0`` where it increases with ``v``
  (downwards). The thesis prints its kernels for MATLAB's ``conv2`` and two of them (central and
  separated central difference) have the opposite column sign of the others: irrelevant for the
  magnitude, not for the orientation (6.15); here each pair is multiplied by the sign of its
  response to a ramp. With ``normalize=True`` it is also divided by that response (its *gain*),
  so ``E_u ≈ ∂I/∂u`` in intensity per pixel for every operator.
* Magnitude (6.14): the mean of ``|E_i|`` over an operator's ``n`` responses
  (``magnitude="mean_abs"``), or the Euclidean norm ``sqrt(Σ E_i²)`` (``"euclidean"``). For
  Frei–Chen it is the norm of the weighted feature projection ``sqrt(Σ w_k p_k²)``.
* Orientation (6.15): ``θ = atan2(E_v, E_u)`` taken modulo π, in ``[0, π)`` — the direction of the
  gradient measured from the ``+u`` axis towards ``+v`` (clockwise as an image is displayed);
  opposite gradients (bone dark on bright, or bright on dark) share one orientation. Roberts'
  diagonal differences ``d₁`` (towards ``(+u, -v)``) and ``d₂`` (towards ``(+u, +v)``) give
  ``E_u = (d₁ + d₂)/2``, ``E_v = (d₂ - d₁)/2``; Frei–Chen uses its two gradient masks; Laplacian
  line gives the normal of the strongest line kernel (0, π/4, π/2 or 3π/4); Laplacian point has
  no orientation (NaN).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from .._validate import as_float_array

__all__ = [
    "FIRST_DERIVATIVE_OPERATORS",
    "OPERATORS",
    "EdgeMap",
    "derivative_kernels",
    "detect_edges",
    "frei_chen_basis",
    "gradient",
    "operator_kernels",
]

_S2 = np.sqrt(2.0)

# kernels exactly as printed in thesis §6.4 (rows = "H_rows", columns = "H_columns")
_PRINTED: dict[str, dict[str, np.ndarray]] = {
    "central_difference": {
        "rows": np.array([[0, 0, 0], [0, 1, -1], [0, 0, 0]], float),
        "columns": np.array([[0, -1, 0], [0, 1, 0], [0, 0, 0]], float),
    },
    "separated_central_difference": {
        "rows": np.array([[0, 0, 0], [1, 0, -1], [0, 0, 0]], float),
        "columns": np.array([[0, -1, 0], [0, 0, 0], [0, 1, 0]], float),
    },
    "roberts": {
        "rows": np.array([[0, 0, -1], [0, 1, 0], [0, 0, 0]], float),
        "columns": np.array([[-1, 0, 0], [0, 1, 0], [0, 0, 0]], float),
    },
    "prewitt": {
        "rows": np.array([[3, 0, -3], [3, 0, -3], [3, 0, -3]], float) / 3.0,
        "columns": np.array([[3, 3, 3], [0, 0, 0], [-3, -3, -3]], float) / 3.0,
    },
    "sobel": {
        "rows": np.array([[1, 0, -1], [2, 0, -2], [1, 0, -1]], float) / 4.0,
        "columns": np.array([[1, 2, 1], [0, 0, 0], [-1, -2, -1]], float) / 4.0,
    },
    "laplacian_point": {
        "point": np.array([[-2, 1, -2], [1, 4, 1], [-2, 1, -2]], float) / 8.0,
    },
    "laplacian_line": {
        "vertical": np.array([[-1, 2, -1], [-1, 2, -1], [-1, 2, -1]], float) / 6.0,
        "horizontal": np.array([[-1, -1, -1], [2, 2, 2], [-1, -1, -1]], float) / 6.0,
        "diagonal_rising": np.array([[-1, -1, 2], [-1, 2, -1], [2, -1, -1]], float) / 6.0,
        "diagonal_falling": np.array([[2, -1, -1], [-1, 2, -1], [-1, -1, 2]], float) / 6.0,
    },
}
_ABDOU_ROW = np.array(
    [
        [1, 1, 1, 0, -1, -1, -1],
        [1, 2, 2, 0, -2, -2, -1],
        [1, 2, 3, 0, -3, -2, -1],
        [1, 2, 3, 0, -3, -2, -1],
        [1, 2, 3, 0, -3, -2, -1],
        [1, 2, 2, 0, -2, -2, -1],
        [1, 1, 1, 0, -1, -1, -1],
    ],
    float,
)
_ABDOU_COL = np.array(
    [
        [-1, -1, -1, -1, -1, -1, -1],
        [-1, -2, -2, -2, -2, -2, -1],
        [-1, -2, -3, -3, -3, -2, -1],
        [0, 0, 0, 0, 0, 0, 0],
        [1, 2, 3, 3, 3, 2, 1],
        [1, 2, 2, 2, 2, 2, 1],
        [1, 1, 1, 1, 1, 1, 1],
    ],
    float,
)
_PRINTED["abdou"] = {"rows": _ABDOU_ROW / 34.0, "columns": _ABDOU_COL / 34.0}

#: normals (θ, radians) of the Laplacian line kernels' lines, in the order of their responses
_LINE_NORMALS = np.array([0.0, np.pi / 2, np.pi / 4, 3 * np.pi / 4])

FIRST_DERIVATIVE_OPERATORS = (
    "central_difference",
    "separated_central_difference",
    "roberts",
    "prewitt",
    "sobel",
    "abdou",
    "frei_chen",
    "gaussian",
)
OPERATORS = (
    "central_difference",
    "separated_central_difference",
    "roberts",
    "prewitt",
    "sobel",
    "laplacian_point",
    "laplacian_line",
    "abdou",
    "frei_chen",
    "gaussian",
)


def frei_chen_basis() -> np.ndarray:
    """The nine orthonormal Frei–Chen masks ``(9, 3, 3)``: G1–G4 edges, G5–G8 lines, G9 mean.

    G1 and G2 are the isotropic gradient masks (vertical and horizontal), G3–G4 the diagonal edge
    masks ("ripples"), G5–G6 line masks, G7–G8 discrete Laplacians, G9 the local average.
    """
    g = np.array(
        [
            [[1, _S2, 1], [0, 0, 0], [-1, -_S2, -1]],
            [[1, 0, -1], [_S2, 0, -_S2], [1, 0, -1]],
            [[0, -1, _S2], [1, 0, -1], [-_S2, 1, 0]],
            [[_S2, -1, 0], [-1, 0, 1], [0, 1, -_S2]],
        ]
    ) / (2 * _S2)
    h = np.array([[[0, 1, 0], [-1, 0, -1], [0, 1, 0]], [[-1, 0, 1], [0, 0, 0], [1, 0, -1]]]) / 2.0
    k = np.array([[[1, -2, 1], [-2, 4, -2], [1, -2, 1]], [[-2, 1, -2], [1, 4, 1], [-2, 1, -2]]]) / 6.0
    return np.concatenate([g, h, k, np.full((1, 3, 3), 1.0 / 3.0)])


def operator_kernels(operator: str) -> dict[str, np.ndarray]:
    """The kernels of ``operator`` as printed in thesis §6.4 (copies).

    ``frei_chen`` returns ``G1`` … ``G9``; ``gaussian`` has no fixed kernel (it depends on σ) and
    raises ``ValueError``.
    """
    op = _check_operator(operator)
    if op == "frei_chen":
        return {f"G{i + 1}": b.copy() for i, b in enumerate(frei_chen_basis())}
    if op == "gaussian":
        raise ValueError("operator: 'gaussian' has no fixed kernel (derivative of a Gaussian of sigma px)")
    return {k: v.copy() for k, v in _PRINTED[op].items()}


def _check_operator(operator: str) -> str:
    if operator not in OPERATORS:
        raise ValueError(f"operator: expected one of {OPERATORS}, got {operator!r}")
    return operator


def _correlate(image: np.ndarray, kernel: np.ndarray) -> np.ndarray:
    return ndimage.correlate(image, kernel, mode="nearest")


def _ramp_gain(kernel: np.ndarray, axis: int) -> float:
    """Response of a correlation with ``kernel`` to the unit ramp ``I = u`` (axis 1) or ``v`` (0)."""
    n = kernel.shape[0] // 2
    off = np.arange(-n, n + 1, dtype=float)
    ramp = off[None, :] if axis == 1 else off[:, None]
    return float((kernel * ramp).sum())


def derivative_kernels(operator: str, *, normalize: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Correlation kernels ``(k_u, k_v)`` of a first-derivative operator (not ``"gaussian"``).

    ``image ⋆ k_u`` is ``E_u`` of the module docs: ``∂I/∂u`` (intensity per pixel) when
    ``normalize`` is True, the printed kernel with its sign made consistent otherwise. Roberts'
    pair is combined from its two diagonal kernels (``E_u = (d₁ + d₂)/2``, ``E_v = (d₂ - d₁)/2``).
    """
    op = _check_operator(operator)
    if op not in FIRST_DERIVATIVE_OPERATORS or op == "gaussian":
        raise ValueError(
            f"operator: expected a first-derivative operator with fixed kernels, got {operator!r}")
    if op == "frei_chen":
        b = frei_chen_basis()
        ku, kv = b[1], b[0]
    elif op == "roberts":
        k1, k2 = _PRINTED["roberts"]["rows"], _PRINTED["roberts"]["columns"]
        ku, kv = (k2 - k1) / 2.0, (k1 + k2) / 2.0
    else:
        ku, kv = _PRINTED[op]["rows"], _PRINTED[op]["columns"]
    gu, gv = _ramp_gain(ku, 1), _ramp_gain(kv, 0)
    su = 1.0 / gu if normalize else float(np.sign(gu))
    sv = 1.0 / gv if normalize else float(np.sign(gv))
    return ku * su, kv * sv


def _first_derivative_pair(image: np.ndarray, op: str, sigma: float, normalize: bool):
    """``(E_u, E_v, responses, names)`` for a first-derivative operator."""
    if op == "gaussian":  # truncated at 4 σ; divided by its ramp gain so that E_u = ∂I/∂u exactly
        m = int(4 * sigma + 2)
        gain = float(ndimage.gaussian_filter1d(np.arange(-m, m + 1.0), sigma, order=1)[m])
        eu = ndimage.gaussian_filter(image, sigma, order=(0, 1), mode="nearest") / gain
        ev = ndimage.gaussian_filter(image, sigma, order=(1, 0), mode="nearest") / gain
        return eu, ev, np.stack([eu, ev]), ("u", "v")
    if op == "roberts":
        # the two diagonal differences, each made positive along its diagonal (ramp gain 1 in u)
        d1 = -_correlate(image, _PRINTED["roberts"]["rows"])  # I(r-1, c+1) - I(r, c): (+u, -v)
        d2 = _correlate(image, _PRINTED["roberts"]["columns"])  # I(r, c) - I(r-1, c-1): (+u, +v)
        return (d1 + d2) / 2.0, (d2 - d1) / 2.0, np.stack([d1, d2]), ("rows", "columns")
    ku, kv = derivative_kernels(op, normalize=normalize)
    eu, ev = _correlate(image, ku), _correlate(image, kv)
    names = ("G2", "G1") if op == "frei_chen" else ("rows", "columns")
    return eu, ev, np.stack([eu, ev]), names


def gradient(image, *, operator: str = "sobel", sigma: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Image gradient ``(E_u, E_v)`` (float64, ``∂I/∂u`` and ``∂I/∂v`` in intensity per pixel).

    Parameters
    ----------
    image : (H, W) array
    operator : str
        One of :data:`FIRST_DERIVATIVE_OPERATORS` (gain-normalised, see the module docs).
    sigma : float
        Gaussian pre-smoothing σ in pixels (0 = none); for ``"gaussian"`` the σ of the
        derivative-of-Gaussian kernels (must be > 0).
    """
    img = _check_image(image)
    if operator not in FIRST_DERIVATIVE_OPERATORS:
        raise ValueError(f"operator: expected a first-derivative operator {FIRST_DERIVATIVE_OPERATORS}, "
                         f"got {operator!r}")
    sigma = _check_sigma(sigma, operator)
    if sigma > 0 and operator != "gaussian":
        img = ndimage.gaussian_filter(img, sigma, mode="nearest")
    eu, ev, _, _ = _first_derivative_pair(img, operator, sigma, True)
    return eu, ev


@dataclass(frozen=True, eq=False)
class EdgeMap:
    """Edge responses of one operator on one image.

    Attributes
    ----------
    operator : str
    responses : (n, H, W) float64
        The directional responses ``E_i`` (named in ``names``).
    names : tuple of str
    magnitude : (H, W) float64
        Eq. 6.14 (or the Euclidean norm / Frei–Chen projection norm; see the module docs).
    orientation : (H, W) float64
        Eq. 6.15 modulo π, radians in ``[0, π)``; NaN for ``laplacian_point``.
    feature : (H, W) float64 or None
        Frei–Chen only: ``sqrt(Σ w_k p_k² / Σ_k p_k²)`` in [0, 1], the cosine of the angle between
        the 3 × 3 neighbourhood and the weighted feature subspace (1 = a pure feature, 0 where the
        neighbourhood is all zero).
    """

    operator: str
    responses: np.ndarray
    names: tuple[str, ...]
    magnitude: np.ndarray
    orientation: np.ndarray
    feature: np.ndarray | None = None


def _check_image(image) -> np.ndarray:
    img = as_float_array(image, "image", ndim=2)
    if min(img.shape) < 1:
        raise ValueError(f"image: expected a non-empty 2-D array, got shape {img.shape}")
    return img


def _check_sigma(sigma: float, operator: str) -> float:
    try:
        s = float(sigma)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"sigma: expected a number of pixels >= 0, got {sigma!r}") from exc
    if not np.isfinite(s) or s < 0:
        raise ValueError(f"sigma: expected a number of pixels >= 0, got {sigma!r}")
    if operator == "gaussian" and s <= 0:
        raise ValueError("sigma: the 'gaussian' (derivative-of-Gaussian) operator needs sigma > 0 px")
    return s


def detect_edges(
    image,
    operator: str = "sobel",
    *,
    sigma: float = 0.0,
    normalize: bool = False,
    magnitude: str = "mean_abs",
    weights=None,
) -> EdgeMap:
    """Apply one of the §6.4 edge operators.

    Parameters
    ----------
    image : (H, W) array
        Grey levels (any units; magnitudes are in the same units per pixel).
    operator : str
        One of :data:`OPERATORS`.
    sigma : float
        Gaussian pre-smoothing σ in pixels (0 = none); for ``"gaussian"`` the σ of the
        derivative-of-Gaussian kernels (> 0).
    normalize : bool
        Divide first-derivative pairs by their ramp gain (``E ≈ ∂I/∂u``); default False keeps the
        thesis' printed scaling (signs are always made consistent, see the module docs).
    magnitude : {"mean_abs", "euclidean"}
        Eq. 6.14 (mean of ``|E_i|``) or ``sqrt(Σ E_i²)``. Ignored for Frei–Chen.
    weights : (9,) array, optional
        Frei–Chen feature weights of G1…G9 (default: the edge subspace, ``(1, 1, 1, 1, 0, …, 0)``);
        e.g. ``(0, 0, 0, 0, 1, 1, 1, 1, 0)`` detects lines (a wire grid, a pressure-plate mesh).

    Returns
    -------
    EdgeMap
    """
    img = _check_image(image)
    op = _check_operator(operator)
    sigma = _check_sigma(sigma, op)
    if magnitude not in ("mean_abs", "euclidean"):
        raise ValueError(f"magnitude: expected 'mean_abs' or 'euclidean', got {magnitude!r}")
    if weights is not None and op != "frei_chen":
        raise ValueError("weights: only the 'frei_chen' operator takes feature weights")
    if sigma > 0 and op != "gaussian":
        img = ndimage.gaussian_filter(img, sigma, mode="nearest")

    def norm(resp: np.ndarray) -> np.ndarray:
        if magnitude == "mean_abs":
            return np.abs(resp).mean(axis=0)
        return np.sqrt((resp * resp).sum(axis=0))

    if op == "frei_chen":
        w = np.array([1, 1, 1, 1, 0, 0, 0, 0, 0], float) if weights is None else as_float_array(
            weights, "weights", shape=(9,))
        if np.any(w < 0) or w.sum() <= 0:
            raise ValueError("weights: expected 9 non-negative Frei–Chen weights with a positive sum")
        p = np.stack([_correlate(img, b) for b in frei_chen_basis()])
        p2 = p * p
        mag = np.sqrt(np.tensordot(w, p2, axes=1))
        total = p2.sum(axis=0)
        feature = np.sqrt(np.divide(np.tensordot(w, p2, axes=1), total, out=np.zeros_like(total),
                                    where=total > 0))
        theta = np.mod(np.arctan2(-p[0], -p[1]), np.pi)  # -G2 ~ +d/du, -G1 ~ +d/dv
        return EdgeMap(op, p, tuple(f"G{i + 1}" for i in range(9)), mag, theta, np.minimum(feature, 1.0))
    if op in ("laplacian_point", "laplacian_line"):
        ks = _PRINTED[op]
        resp = np.stack([_correlate(img, k) for k in ks.values()])
        if op == "laplacian_point":
            theta = np.full(img.shape, np.nan)
        else:
            theta = _LINE_NORMALS[np.argmax(np.abs(resp), axis=0)]
        return EdgeMap(op, resp, tuple(ks), norm(resp), theta)
    eu, ev, resp, names = _first_derivative_pair(img, op, sigma, normalize)
    # Roberts: magnitude from its two diagonal responses, orientation from (E_u, E_v)
    return EdgeMap(op, resp, names, norm(resp), np.mod(np.arctan2(ev, eu), np.pi))
