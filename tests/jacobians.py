"""The one generic Jacobian harness: analytic Jacobians of a factor against central differences on
the manifold (GTSAM ``retract`` / ``localCoordinates`` semantics), float64.

``check_factor_jacobians`` works for any ``gtsam.NoiseModelFactor`` (CustomFactor, PriorFactor,
BetweenFactor, projection factors...) on any keys held by ``values``: it perturbs each key's
tangent coordinates through ``Values.retract`` and differentiates ``whitenedError``.
``check_ceres_cost_jacobians`` does the same for a pyceres cost function in its own
parametrisation: ambient coordinates, and on the manifold through each block's plus.
"""

from __future__ import annotations

from collections.abc import Callable

import gtsam
import numpy as np


def _numeric(f: Callable[[np.ndarray], np.ndarray], dim: int, eps: float) -> np.ndarray:
    cols = []
    for i in range(dim):
        d = np.zeros(dim)
        d[i] = eps
        cols.append((f(d) - f(-d)) / (2 * eps))
    return np.stack(cols, axis=1)


def _assert_close(A: np.ndarray, N: np.ndarray, rtol: float, atol: float, what: str) -> float:
    scale = max(1.0, float(np.abs(N).max()))
    err = float(np.abs(A - N).max())
    if not err <= atol + rtol * scale:
        raise AssertionError(f"{what}: analytic vs central differences differ by {err:.3e} "
                             f"(scale {scale:.3e}, allowed {atol + rtol * scale:.3e})\nanalytic=\n{A}\nnumeric=\n{N}")
    return err / scale


def check_factor_jacobians(factor, values: gtsam.Values, eps: float = 1e-6, rtol: float = 1e-6,
                           atol: float = 1e-8) -> float:
    """Assert ``factor.linearize(values)`` equals central differences of ``factor.whitenedError``.

    Each key of the factor is perturbed by ``+-eps`` along each tangent axis through
    ``values.retract`` (the factor's manifold). Tolerance: ``|A - N| <= atol + rtol * max(1, |N|)``
    elementwise. Returns the worst relative difference. Raises AssertionError with both matrices.
    """
    lin = factor.linearize(values)
    A, b = lin.jacobian()
    np.testing.assert_allclose(-b, factor.whitenedError(values), rtol=1e-12, atol=1e-12,
                               err_msg="linearize b != -whitenedError")
    zero = values.zeroVectors()
    cols = []
    for key in factor.keys():
        dim = zero.at(key).shape[0]

        def f(d, key=key):
            delta = values.zeroVectors()
            one = gtsam.VectorValues()
            one.insert(key, d)
            delta.update(one)
            return factor.whitenedError(values.retract(delta))

        cols.append(_numeric(f, dim, eps))
    N = np.concatenate(cols, axis=1)
    return _assert_close(A, N, rtol, atol, f"factor on keys {list(factor.keys())}")


def quaternion_plus_xyzw(q: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Ceres's EigenQuaternionManifold plus: ``[sin|d| d/|d|, cos|d|] * q`` (Eigen order x, y, z, w)."""
    n = np.linalg.norm(d)
    dq = np.concatenate([np.sin(n) / n * d, [np.cos(n)]]) if n > 0 else np.array([0.0, 0.0, 0.0, 1.0])
    x1, y1, z1, w1 = dq
    x2, y2, z2, w2 = q
    return np.array([
        w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
        w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
        w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
        w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
    ])


def check_ceres_cost_jacobians(cost, params: list[np.ndarray], plus: list[Callable | None], eps: float = 1e-6,
                               rtol: float = 1e-6, atol: float = 1e-8) -> float:
    """Check a pyceres ``CostFunction`` (Python subclass) through its own ``Evaluate``.

    params: the parameter blocks (ambient). plus: per block, the manifold plus ``(x, delta) -> x'``
    or None for a Euclidean block. Checks (1) the ambient Jacobians against central differences in
    ambient coordinates and (2) ``J_ambient @ d plus / d delta`` against central differences
    through ``plus`` (tangent coordinates). Returns the worst relative difference.
    """
    sizes = [len(p) for p in params]
    m = cost.num_residuals()

    def evaluate(ps, want_jac=True):
        res = np.zeros(m)
        jacs = [np.zeros(m * s) for s in sizes] if want_jac else None
        assert cost.Evaluate([np.asarray(p, np.float64) for p in ps], res, jacs)
        return res, ([j.reshape(m, s) for j, s in zip(jacs, sizes)] if want_jac else None)

    _, J = evaluate(params)
    worst = 0.0
    for i in range(len(params)):
        def f_amb(d, i=i):
            ps = [q.copy() for q in params]
            ps[i] = ps[i] + d
            return evaluate(ps, False)[0]

        worst = max(worst, _assert_close(J[i], _numeric(f_amb, sizes[i], eps), rtol, atol, f"ambient block {i}"))
        if plus[i] is not None:
            tdim = sizes[i] - 1 if sizes[i] == 4 else sizes[i]
            P = _numeric(lambda d, i=i: plus[i](params[i], d), tdim, eps)

            def f_tan(d, i=i):
                ps = [q.copy() for q in params]
                ps[i] = plus[i](params[i], d)
                return evaluate(ps, False)[0]

            worst = max(worst, _assert_close(J[i] @ P, _numeric(f_tan, tdim, eps), rtol, atol, f"tangent block {i}"))
    return worst


def check_se3_residual_jacobian(fn: Callable[[np.ndarray], tuple[float | np.ndarray, np.ndarray]], T: np.ndarray,
                                eps: float = 1e-6, rtol: float = 1e-6, atol: float = 1e-8) -> float:
    """Assert the analytic Jacobian of a numpy residual on ``T_cam_radar`` (4, 4) equals central
    differences along the right perturbation ``T exp([phi, rho])`` (GTSAM order, docs/conventions.md).

    ``fn(T) -> (r, J)`` with r scalar or (m,), J (6,) or (m, 6). Returns the worst relative difference.
    """
    from hybrid_calib.geometry import retract

    r0, J = fn(T)
    J = np.atleast_2d(np.asarray(J, np.float64))
    N = _numeric(lambda d: np.atleast_1d(np.asarray(fn(retract(T, d))[0], np.float64)), 6, eps)
    return _assert_close(J, N, rtol, atol, "se3 residual")
