"""The reference path of the keyframe solve: ``scipy.optimize.least_squares`` (trust region
reflective) on F(x) = 1/2 |r(x)|^2 with the analytic sparse Jacobian of ``posefix.core.terms``.

Slow and general; the tests hold the fast banded path (``solver.solve_banded``) to its answer.
"""

from __future__ import annotations

import time

import numpy as np

from posefix.core import terms as T
from posefix.core.solver import SolverResult, solve_banded


def solve_scipy(
    terms: T.Terms,
    x0: np.ndarray | None = None,
    max_iterations: int = 200,
    ftol: float = 1e-12,
) -> tuple[np.ndarray, SolverResult]:
    """Reference path: scipy.optimize.least_squares (TRF) with the analytic sparse Jacobian."""
    from scipy.optimize import least_squares

    started = time.perf_counter()
    x0 = T.initial_state(terms) if x0 is None else np.asarray(x0, dtype=float)
    before = T.evaluate(terms, x0, with_jac=False).costs()

    def fun(x):
        return T.evaluate(terms, x, with_jac=False).residual_vector()

    def jac(x):
        return T.sparse_jacobian(terms, T.evaluate(terms, x, with_jac=True))

    out = least_squares(
        fun,
        x0,
        jac=jac,
        method="trf",
        tr_solver="lsmr",
        tr_options={"atol": 1e-14, "btol": 1e-14, "maxiter": 20 * len(x0)},
        x_scale="jac",
        ftol=ftol,
        xtol=1e-14,
        gtol=1e-14,
        max_nfev=max_iterations,
    )
    status = "converged" if out.status > 0 else ("max_iterations" if out.status == 0 else "failed")
    return out.x, SolverResult(
        status=status,
        message=str(out.message),
        iterations=int(out.nfev),
        cost_before=before,
        cost_after=T.evaluate(terms, out.x, with_jac=False).costs(),
        time_s=time.perf_counter() - started,
        method="scipy-trf",
    )


def solve(terms: T.Terms, x0=None, method: str = "banded", max_iterations: int = 100, ftol: float = 1e-10):
    """Dispatch to the configured solver path."""
    if method == "banded":
        return solve_banded(terms, x0, max_iterations=max_iterations, ftol=ftol)
    if method == "scipy":
        return solve_scipy(terms, x0, max_iterations=max(max_iterations, 200), ftol=ftol)
    raise ValueError(f"unknown solver method {method!r}")
