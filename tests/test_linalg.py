"""ditherlab.core.linalg: the compiled solves against numpy's LAPACK (their slow, obviously right
reference), their refusals, and the norm."""

from __future__ import annotations

import numpy as np
import pytest

from ditherlab.core.linalg import cholesky, lu_solve, spd_inverse, spd_solve, vector_norm
from ditherlab.robot import RobotModel


def _spd(rng: np.random.Generator, n: int) -> np.ndarray:
    A = rng.normal(size=(n, n))
    return A @ A.T + n * np.eye(n)


def test_spd_inverse_is_the_inverse():
    """On random symmetric positive definite matrices and the IRB140's link mass matrices at
    random poses: the inverse to 1e-12 relative, exactly symmetric; a matrix that is not
    positive definite is refused."""
    rng = np.random.default_rng(3)
    robot = RobotModel.from_spec("irb140")
    mats = [_spd(rng, n) for n in (1, 2, 6, 7)]
    q = rng.uniform(-1.5, 1.5, size=(5, 6))
    M = robot.evaluate(q, ["mass_matrix"], reference=True)["mass_matrix"]
    mats += list(M + 0.01 * np.eye(6))
    for A in mats:
        W = spd_inverse(np.ascontiguousarray(A))
        np.testing.assert_array_equal(W, W.T)
        ref = np.linalg.inv(A)
        assert np.max(np.abs(W - ref)) <= 1e-12 * np.max(np.abs(ref))
    with pytest.raises(ValueError, match="not positive definite"):
        spd_inverse(np.diag([1.0, -1.0]))


def test_cholesky_and_spd_solve():
    """``L Lᵀ = A`` to 1e-13; ``spd_solve`` equals numpy's solve to 1e-11; None for a matrix
    that is not positive definite (a zero or negative pivot, or NaN); a ``b`` of the wrong
    length is an error, not a read past the matrix."""
    rng = np.random.default_rng(5)
    for n in (1, 3, 6):
        A = _spd(rng, n)
        L = cholesky(A)
        np.testing.assert_allclose(L @ L.T, A, rtol=1e-13, atol=1e-13)
        assert np.all(np.triu(L, 1) == 0.0)
        b = rng.normal(size=n)
        np.testing.assert_allclose(spd_solve(A, b), np.linalg.solve(A, b), rtol=1e-11, atol=1e-12)
    assert cholesky(np.diag([1.0, 0.0])) is None
    assert spd_solve(np.diag([1.0, -1.0]), np.ones(2)) is None
    assert spd_solve(np.array([[np.nan]]), np.ones(1)) is None
    with pytest.raises(ValueError, match="spd_solve"):
        spd_solve(np.eye(3), np.ones(2))


def test_lu_solve_is_the_pseudo_inverse_for_a_square_jacobian():
    """The lead-through's joint rates: ``lu_solve(J, v)`` equals ``pinv(J) @ v`` for the
    IRB140's Jacobians at random poses and near the wrist singularity (q5 -> 0), relative to
    cond(J) times the machine epsilon; None at the singular pose itself and for dependent
    rows; a ``b`` of the wrong length is an error."""
    rng = np.random.default_rng(7)
    robot = RobotModel.from_spec("irb140")
    q = rng.uniform(-1.2, 1.2, size=(6, 6))
    q[-3:, 4] = [1e-2, 1e-3, 1e-4]  # towards the wrist singularity
    for J in robot.evaluate(q, ["jacobian"])["jacobian"]:
        t = rng.normal(size=6)
        ref = np.linalg.pinv(J) @ t
        got = lu_solve(np.ascontiguousarray(J), t)
        tol = 50 * np.linalg.cond(J) * np.finfo(float).eps
        assert np.max(np.abs(got - ref)) <= tol * np.max(np.abs(ref))
    q0 = q[0].copy()
    q0[4] = 0.0
    Js = robot.evaluate(q0[None], ["jacobian"])["jacobian"][0]
    assert lu_solve(np.ascontiguousarray(Js), np.ones(6)) is None
    J = robot.evaluate(q[:1], ["jacobian"])["jacobian"][0].copy()
    J[1] = J[0]
    assert lu_solve(J, np.ones(6)) is None
    with pytest.raises(ValueError, match="lu_solve"):
        lu_solve(np.eye(3), np.ones(4))


def test_vector_norm():
    """Equal to ``np.linalg.norm`` to the last bits on random vectors; 0 for zeros."""
    rng = np.random.default_rng(9)
    for v in (rng.normal(size=3), rng.normal(size=7), 1e150 * rng.normal(size=2)):
        assert vector_norm(v) == pytest.approx(np.linalg.norm(v), rel=1e-15, abs=0.0)
    assert vector_norm(np.zeros(3)) == 0.0
