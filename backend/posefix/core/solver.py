"""Solvers for the keyframe problem of ``posefix.core.terms``: minimise F(x) = 1/2 |r(x)|^2.

Two paths reach the same minimum:

* ``solve_banded`` (fast path): Levenberg-Marquardt.  Each iteration solves
  ``(J^T J + lambda diag(J^T J)) dx = -J^T r``.  Every term links at most two neighbouring
  keyframes, so with the state ordered keyframe by keyframe (6 unknowns each) ``J^T J`` is
  symmetric block-tridiagonal: a band of 11 super-diagonals.  It is stored in LAPACK's
  upper banded form and factorised by ``banded.factor`` (LAPACK's banded Cholesky from
  numpy's own OpenBLAS, else block cyclic reduction in numpy; O(k * 6^3)).  The robust location loss is already inside the residual (see terms.py), so
  the Gauss-Newton model is that of the exact cost; the gain ratio steers lambda
  (Nielsen's rule: lambda *= max(1/3, 1 - (2 rho - 1)^3) on success, *= nu, nu *= 2 on failure).
* ``solver_reference.solve_scipy`` (reference path; ``solver_reference.solve`` dispatches between the two): ``scipy.optimize.least_squares`` (trust region
  reflective) with the analytic sparse Jacobian.

Both return the solution and a ``SolverResult``.  For one more edit on a solved run,
``solve_local_newton`` takes Newton steps on a window of keyframes from the warm start with
only the robust location term re-modelled at each step; the other terms' model is the
``Linearisation`` that ``solve_banded(..., linearise=True)`` kept at its answer (the
relative and gravity terms depend on the keyframes, not on the edits), or is built at the
warm start when there is none.
"""

from __future__ import annotations

import dataclasses
import functools
import time
from dataclasses import dataclass, field

import numpy as np
from posefix.core import banded
from posefix.core import terms as T
from posefix.core.banded import LinAlgError

BAND_U = 11  # super-diagonals of a block-tridiagonal matrix with 6x6 blocks
CHORD_AFTER_STEPS = 30  # local Newton: after a step under this many step tolerances, re-use the factorisation


@dataclass(frozen=True)
class SolverResult:
    """What a solve did: status ("converged" | "max_iterations" | "failed"), message,
    iterations, cost per term before and after, wall time in seconds, method."""

    status: str
    message: str
    iterations: int
    cost_before: dict[str, float]
    cost_after: dict[str, float]
    time_s: float
    method: str
    extra: dict = field(default_factory=dict)

    @property
    def success(self) -> bool:
        return self.status == "converged"

    @property
    def cost(self) -> float:
        return float(sum(self.cost_after.values()))

    def to_json(self) -> dict:
        return {
            "status": self.status,
            "message": self.message,
            "iterations": self.iterations,
            "cost_before": self.cost_before,
            "cost_after": self.cost_after,
            "cost": self.cost,
            "time_s": self.time_s,
            "method": self.method,
        }


@dataclass(frozen=True)
class Linearisation:
    """Gauss-Newton model of the relative and gravity terms of a solved run at its solution ``x_lin``.

    Those terms depend (almost) on the keyframes alone, so the model built when a run is
    solved serves the next local solve after one more edit, as iSAM2 keeps the linearisation
    of its previous update: the local solve then only adds the location and user terms of
    its window (and re-weights any relative-translation edge whose weight the edits changed).
    The model stays valid while orientations stay within about a milliradian of ``x_lin``
    (its error is of order (d theta)^2); ``solve_local_newton`` checks that.

    x_lin (6k,) state it was built at; ab (12, 6k) J^T J in LAPACK's upper band form
    (``pack_banded``, Fortran order); g (6k,) J^T r at x_lin; cost_rt, cost_rr (k-1,),
    cost_g (k,) each term's cost 1/2 |r|^2 at x_lin per edge / keyframe; rt_PtT, rt_TtT
    (k-1,3,3), rt_Pte, rt_Tte (k-1,3) the relative-translation terms' blocks at unit weight
    (see ``_reweight_relative_translation``); rel_w_t, rel_w_r (k-1,), grav_w (k,) the
    weights it was built with;
    R_rep, rel_delta_m the reported poses' arrays it was built on (to tell its keyframes).
    Read only: shared by every solution warm-started from it.
    """

    x_lin: np.ndarray
    ab: np.ndarray
    g: np.ndarray
    cost_rt: np.ndarray
    cost_rr: np.ndarray
    cost_g: np.ndarray
    rt_PtT: np.ndarray
    rt_TtT: np.ndarray
    rt_Pte: np.ndarray
    rt_Tte: np.ndarray
    rel_w_t: np.ndarray
    rel_w_r: np.ndarray
    grav_w: np.ndarray
    R_rep: np.ndarray
    rel_delta_m: np.ndarray

    def matches(self, terms: T.Terms) -> bool:
        """True when ``terms`` lies on the same keyframes with the same reported motion and the
        same rotation and gravity weights (relative-translation weights may differ: see window)."""
        return (
            terms.n_keyframes == len(self.g) // 6
            and T.same_array(self.R_rep, terms.R_rep)
            and T.same_array(self.rel_delta_m, terms.rel_delta_m)
            and T.same_array(self.rel_w_r, terms.rel_w_r)
            and T.same_array(self.grav_w, terms.grav_w)
        )

    def window(self, lo: int, hi: int) -> "WindowModel":
        """The model on keyframes lo..hi (views).  The end blocks still hold the terms linking
        lo - 1 and hi + 1: right only where those keyframes are held."""
        return WindowModel(self.x_lin[6 * lo:6 * hi + 6], self.ab[:, 6 * lo:6 * hi + 6],
                           self.g[6 * lo:6 * hi + 6], self.rel_w_t[lo:hi], self.rt_PtT[lo:hi], self.rt_TtT[lo:hi],
                           self.rt_Pte[lo:hi], self.rt_Tte[lo:hi])

    def window_costs(self, lo: int, hi: int, rel_w_t: np.ndarray | None = None) -> dict[str, float]:
        """Costs at x_lin of the relative and gravity terms touching only keyframes lo..hi;
        with ``rel_w_t`` (hi - lo,) those of the relative-translation terms re-weighted
        (a whitened residual's cost goes with its weight squared)."""
        cost_rt = self.cost_rt[lo:hi]
        if rel_w_t is not None and rel_w_t is not self.rel_w_t[lo:hi]:
            cost_rt = cost_rt * (rel_w_t / self.rel_w_t[lo:hi]) ** 2
        return {
            "relative_translation": float(cost_rt.sum()),
            "relative_rotation": float(self.cost_rr[lo:hi].sum()),
            "gravity": float(self.cost_g[lo:hi + 1].sum()),
        }


@dataclass(frozen=True)
class WindowModel:
    """``Linearisation`` on a window: x_lin (6n,), ab (12, 6n), g (6n,), the
    relative-translation weights (n-1,) it was built with and those terms' unit-weight blocks."""

    x_lin: np.ndarray
    ab: np.ndarray
    g: np.ndarray
    rel_w_t: np.ndarray
    rt_PtT: np.ndarray
    rt_TtT: np.ndarray
    rt_Pte: np.ndarray
    rt_Tte: np.ndarray


def linearise_fixed_terms(terms: T.Terms, ev: T.Evaluation) -> Linearisation:
    """The ``Linearisation`` of ``terms`` at the state ``ev`` was evaluated at (with Jacobians)."""
    no_user = dataclasses.replace(terms, user_idx=terms.user_idx[:0], user_c_m=terms.user_c_m[:0],
                                  user_w=terms.user_w[:0])
    ev_no_user = dataclasses.replace(ev, user_r=ev.user_r[:0], jac={**ev.jac, "user_p": ev.jac["user_p"][:0]})
    D, U, g = T.normal_equations(no_user, ev_no_user, location=False)
    ab = np.asfortranarray(pack_banded(D, U))
    x_lin = np.concatenate([ev.cache["p"], ev.cache["theta"]], axis=1).ravel()
    costs = [0.5 * np.einsum("ij,ij->i", r, r) for r in (ev.rt_r, ev.rr_r, ev.grav_r)]
    # the relative-translation blocks of terms.normal_equations divided by their weight squared
    P, Tt, w2 = ev.jac["rt_pi"], ev.jac["rt_ti"], terms.rel_w_t**2
    Pt = np.swapaxes(P, 1, 2)
    unit = [(Pt @ Tt) / w2[:, None, None], (np.swapaxes(Tt, 1, 2) @ Tt) / w2[:, None, None],
            np.einsum("mri,mr->mi", P, ev.rt_r) / w2[:, None], np.einsum("mri,mr->mi", Tt, ev.rt_r) / w2[:, None]]
    for arr in (x_lin, ab, g, *costs, *unit):
        arr.flags.writeable = False
    return Linearisation(x_lin, ab, g, *costs, *unit, terms.rel_w_t, terms.rel_w_r, terms.grav_w, terms.R_rep,
                         terms.rel_delta_m)


def _reweight_relative_translation(lin: "WindowModel", edges: np.ndarray, scale: np.ndarray,
                                   D: np.ndarray, U: np.ndarray, g: np.ndarray) -> None:
    """Add ``scale`` (m,) times the unit-weight Gauss-Newton blocks of the relative-translation
    terms on ``edges`` (m,) (window numbering; D, U, g numbered from the first edge's keyframe)
    to D, U, g in place.

    With ``e = R_i^T (p_j - p_i) - D_ij`` the unit-weight Jacobian rows are ``[P, T, -P, 0]``
    over (p_i, theta_i, p_j, theta_j), ``P = -R_i^T``, ``T = [R_i^T (p_j - p_i)]x Jr(theta_i)``
    (as in ``terms.normal_equations``): blocks ``I`` (p_i p_i, p_j p_j), ``P^T T`` (p_i theta_i),
    ``T^T T`` (theta_i theta_i), ``-I`` (p_i p_j), ``-T^T P`` (theta_i p_j), gradient ``P^T e``,
    ``T^T e``, ``-P^T e``; the model kept them at x_lin.  A term of weight w contributes w^2
    times them, so a change of weight from w to w' adds (w'^2 - w^2) times them.
    """
    i = edges - edges[0]
    s = scale[:, None, None]
    sPtT = s * lin.rt_PtT[edges]
    eye = s * np.eye(3)
    # whole 6x6 blocks built by slices, then one scatter each (the edges are distinct)
    Di = np.empty((len(i), 6, 6))
    Di[:, :3, :3] = eye
    Di[:, :3, 3:] = sPtT
    Di[:, 3:, :3] = np.swapaxes(sPtT, 1, 2)
    Di[:, 3:, 3:] = s * lin.rt_TtT[edges]
    Dj = np.zeros((len(i), 6, 6))
    Dj[:, :3, :3] = eye
    Ui = np.zeros((len(i), 6, 6))
    Ui[:, :3, :3] = -eye
    Ui[:, 3:, :3] = -np.swapaxes(sPtT, 1, 2)
    D[i] += Di
    D[i + 1] += Dj
    U[i] += Ui
    gs = g.reshape(-1, 6)
    gi = np.empty((len(i), 6))
    gi[:, :3] = scale[:, None] * lin.rt_Pte[edges]
    gi[:, 3:] = scale[:, None] * lin.rt_Tte[edges]
    gs[i] += gi
    gs[i + 1, :3] -= gi[:, :3]


def position_term_costs(terms: T.Terms, p_m: np.ndarray) -> dict[str, float]:
    """Costs of the location and user terms (they depend on positions (k,3) alone)."""
    loc_r, _, _ = T.location_residual(terms, p_m)
    user_r = terms.user_w * (p_m[terms.user_idx] - terms.user_c_m)
    return {"location": 0.5 * float(np.einsum("ij,ij->", loc_r, loc_r)),
            "user": 0.5 * float(np.einsum("ij,ij->", user_r, user_r))}


def pack_banded(D: np.ndarray, U: np.ndarray, damping: np.ndarray | float = 0.0) -> np.ndarray:
    """Symmetric block-tridiagonal matrix -> LAPACK upper band (12, 6k); adds damping to the diagonal."""
    ab = banded.pack_upper(np.asarray(D, dtype=float), np.asarray(U, dtype=float))  # Fortran order
    if np.any(damping):
        ab[BAND_U] += damping
    return ab


def banded_matvec(D: np.ndarray, U: np.ndarray, v: np.ndarray) -> np.ndarray:
    """(J^T J) v for the block-tridiagonal matrix given by D, U."""
    return banded.matvec(D, U, v)


def solve_banded(
    terms: T.Terms,
    x0: np.ndarray | None = None,
    max_iterations: int = 100,
    ftol: float = 1e-10,
    initial_lambda: float = 1e-6,
    fixed: np.ndarray | None = None,
    linearise: bool = False,
) -> tuple[np.ndarray, SolverResult]:
    """Levenberg-Marquardt on the banded normal equations (fast path).

    ``fixed`` (k,) bool marks keyframes held at ``x0`` (boundary of a windowed solve): their
    rows and columns of the normal equations are replaced by the identity, so their step is 0.
    ``linearise`` also returns, in ``extra["linearisation"]``, the ``Linearisation`` of the
    edit-independent terms at the solution (for a later local solve; one more assembly of
    the normal equations, from the Jacobians the last iteration left).
    """
    started = time.perf_counter()
    x = T.initial_state(terms) if x0 is None else np.array(x0, dtype=float, copy=True)
    ev = T.evaluate(terms, x, with_jac=True)
    before = ev.costs()
    F = ev.cost()
    lam, nu = initial_lambda, 2.0
    status, message, it = "max_iterations", f"stopped after {max_iterations} iterations", 0
    accepted = 0
    model_of = None  # the evaluation D, U, g (and their band) were assembled at: a rejected step keeps them
    while it < max_iterations:
        it += 1
        if model_of is not ev:
            D, U, g = T.normal_equations(terms, ev)
            if fixed is not None:
                D[fixed] = np.eye(6)
                g.reshape(-1, 6)[fixed] = 0.0
                U[fixed[:-1] | fixed[1:]] = 0.0
            diag = np.maximum(np.einsum("kii->ki", D).ravel(), 1e-12)
            # packed once per model; each damping only adds to the band's diagonal row
            ab0 = banded.pack_upper(D, U) if banded.has_lapack() else None
            model_of = ev
        gnorm = float(np.max(np.abs(g))) if g.size else 0.0
        if gnorm <= 1e-12 * max(1.0, F):
            status, message = "converged", "gradient is zero to machine precision"
            it -= 1
            break
        try:
            if ab0 is not None:
                ab = ab0.copy(order="F")
                ab[BAND_U] += lam * diag
                dx = banded.solve(banded.factor_upper(ab, 6, overwrite=True), -g)
            else:
                damped = D.copy()
                damped[:, range(6), range(6)] += lam * diag.reshape(-1, 6)
                dx = banded.solve(banded.factor(damped, U), -g)
        except LinAlgError:
            lam, nu = lam * nu, nu * 2.0
            continue
        predicted = -(g @ dx) - 0.5 * dx @ banded_matvec(D, U, dx)
        x_new = x + dx
        ev_new = T.evaluate(terms, x_new, with_jac=False)
        F_new = ev_new.cost()
        actual = F - F_new
        rho = actual / predicted if predicted > 0 else -1.0
        if rho > 0:
            x, accepted = x_new, accepted + 1
            small_step = float(np.max(np.abs(dx))) <= 1e-10 * (1.0 + float(np.max(np.abs(x))))
            ev = T.add_jacobians(terms, ev_new)
            F_old, F = F, F_new
            lam *= max(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3)
            nu = 2.0
            if actual <= ftol * F_old or small_step:
                status, message = "converged", "relative cost decrease below ftol"
                break
        else:
            lam, nu = lam * nu, nu * 2.0
            if lam > 1e12:
                status, message = "converged", "no further decrease possible (damping saturated)"
                break
    if not np.isfinite(F):
        status, message = "failed", "cost is not finite"
    extra = {"accepted_steps": accepted, "lambda": lam}
    if linearise and np.isfinite(F):
        extra["linearisation"] = linearise_fixed_terms(terms, ev if ev.jac else T.evaluate(terms, x))
    return x, SolverResult(
        status=status,
        message=message,
        iterations=it,
        cost_before=before,
        cost_after=ev.costs() if ev.jac else T.evaluate(terms, x, with_jac=False).costs(),
        time_s=time.perf_counter() - started,
        method="banded-lm",
        extra=extra,
    )


def factor_banded_spd(ab: np.ndarray, overwrite: bool = False) -> banded.Factor | banded.BandFactor:
    """Factor of A symmetric positive definite given in upper band form ab (12, 6k)
    (``overwrite``: ab, Fortran-ordered, may hold the factor afterwards)."""
    return banded.factor_upper(ab, 6, overwrite=overwrite)


def solve_with_factor(c: banded.Factor | banded.BandFactor, b: np.ndarray) -> np.ndarray:
    """Solve A x = b given the factor of A (``factor_banded_spd``)."""
    return banded.solve(c, b)


@functools.lru_cache(maxsize=8)
def _position_band_index() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Band rows and column offsets of the upper triangle of a keyframe's 3x3 position block."""
    a, b = np.meshgrid(np.arange(3), np.arange(3), indexing="ij")
    upper = a <= b
    return BAND_U + a[upper] - b[upper], b[upper], a[upper], b[upper]


def _model_from_linearisation(terms: T.Terms, lin: WindowModel) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(x_lin, ab, g_c): a window's ``Linearisation`` plus ``terms``' user terms (copies).

    The user term ``W (p - c)`` is linear in p, so its Gauss-Newton model is exact: ``W^2``
    on the position diagonal, ``W^2 (p_lin - c)`` in the gradient at x_lin.  Relative-
    translation edges whose weight differs from the model's are re-weighted.
    """
    x_lin = lin.x_lin
    ab = np.array(lin.ab, order="F", copy=True)
    g = lin.g.copy()
    if terms.rel_w_t is not lin.rel_w_t:
        edges = np.flatnonzero(terms.rel_w_t != lin.rel_w_t)
        if len(edges):
            # the blocks of keyframes e0..e1 + 1 change: build and pack that stretch only
            e0, e1 = int(edges[0]), int(edges[-1])
            m = e1 - e0 + 2
            dD, dU = np.zeros((m, 6, 6)), np.zeros((m - 1, 6, 6))
            dg = np.zeros(6 * m)
            _reweight_relative_translation(lin, edges, terms.rel_w_t[edges] ** 2 - lin.rel_w_t[edges] ** 2, dD, dU, dg)
            ab[:, 6 * e0:6 * e1 + 12] += pack_banded(dD, dU)
            g[6 * e0:6 * e1 + 12] += dg
    ui = terms.user_idx
    w2 = terms.user_w**2
    ab[BAND_U, (6 * ui[:, None] + np.arange(3)).ravel()] += w2.ravel()  # (at most one user term per keyframe)
    p_lin = x_lin.reshape(-1, 6)[ui, :3]
    g.reshape(-1, 6)[ui, :3] += w2 * np.where(w2 > 0, p_lin - terms.user_c_m, 0.0)
    return x_lin, ab, g


def band_matvec(ab: np.ndarray, v: np.ndarray) -> np.ndarray:
    """A v for A symmetric in upper band form ab (12, 6k) (as ``banded_matvec`` on D, U)."""
    return banded.upper_band_matvec(ab, v)


def _hold_in_band(ab: np.ndarray, fixed: np.ndarray) -> None:
    """Replace the rows and columns of the ``fixed`` keyframes (k,) bool by the identity, in place."""
    h = np.flatnonzero(fixed)
    cols = (6 * h[:, None] + np.arange(6)).ravel()
    ab[:, cols] = 0.0  # a keyframe's columns hold its diagonal block and its coupling to the one before
    ab[BAND_U, cols] = 1.0
    # its coupling to the next keyframe: entry (6h + r, 6(h + 1) + c) sits in band row BAND_U - 6 + r - c
    nxt = h[h + 1 < len(fixed)]
    ab[_NEXT_BAND_ROWS[None, :], 6 * (nxt[:, None] + 1) + _NEXT_COLS[None, :]] = 0.0


# band rows and column offsets of a keyframe's coupling block to the next one (``_hold_in_band``)
_r, _c = np.meshgrid(np.arange(6), np.arange(6), indexing="ij")
_NEXT_BAND_ROWS, _NEXT_COLS = (BAND_U - 6 + _r - _c).ravel(), _c.ravel()
del _r, _c


def _newton_on_model(terms: T.Terms, ab_c: np.ndarray, g_c: np.ndarray, x_lin: np.ndarray,
                     x_start: np.ndarray, fixed, max_steps: int, step_tol_m: float,
                     step_axes: int = 3, chord_after_m: float | None = None) -> tuple[np.ndarray | None, int]:
    """Inner loop of ``solve_local_newton``: every term but location by its model at ``x_lin``
    (J^T J as band ab_c (12, 6n), Fortran order, and gradient g_c there), from ``x_start``."""
    loc_idx = terms.loc_idx
    loc_free = np.ones(len(loc_idx), dtype=bool)
    ab_s = np.array(ab_c, order="F", copy=True)  # the matrix solved: held keyframes fixed, damped
    if fixed is not None:
        _hold_in_band(ab_s, fixed)
        loc_free = ~fixed[loc_idx]
    # a hair of damping keeps the factorisation positive definite where a keyframe has only
    # relative constraints (no fix, no edit)
    ab_s[BAND_U] += 1e-9 * np.maximum(ab_s[BAND_U], 1e-12)
    rows, col_off, ia, ib = _position_band_index()
    # a location term at weight 0 (dropped, or a model without one) adds nothing: with none left
    # the Newton matrix never changes and one factorisation serves every step
    free = np.flatnonzero(loc_free & np.any(terms.loc_w > 0, axis=1))
    li = loc_idx[free]
    # flat places of the located keyframes' position blocks (upper triangle) in the band, read in
    # Fortran order (element (r, c) at c * 12 + r), and of their positions in the state
    band_flat = ((6 * li[:, None] + col_off[None, :]) * (BAND_U + 1) + rows[None, :]).ravel()
    tri = (3 * ia + ib)[None, :]
    g_flat = (6 * li[:, None] + np.arange(3)[None, :]).ravel()
    fixed_rows = None if fixed is None else (6 * np.flatnonzero(fixed)[:, None] + np.arange(6)[None, :]).ravel()
    x = x_start.copy()
    if chord_after_m is None:
        chord_after_m = CHORD_AFTER_STEPS * step_tol_m
    factor, last = None, np.inf  # Cholesky factor of the last Newton matrix; size of the last step (m)
    for step in range(1, max_steps + 1):
        if len(free):
            g_loc, H_loc = T.location_model(terms, x.reshape(-1, 6)[:, :3])
        # the model's gradient with the full matrix: a held keyframe away from x_lin (a window
        # solved before moved it) still pulls its free neighbour
        d = x - x_lin
        g = g_c + band_matvec(ab_c, d) if d.any() else g_c.copy()
        if len(free):
            g[g_flat] += g_loc[free].ravel()
        if fixed_rows is not None:
            g[fixed_rows] = 0.0
        try:
            if factor is None or (len(free) and last > chord_after_m):
                ab = ab_s.copy(order="F")
                if len(free):
                    ab.reshape(-1, order="F")[band_flat] += H_loc.reshape(-1, 9)[free[:, None], tri].ravel()
                factor = factor_banded_spd(ab, overwrite=True)
                chord = False
            else:
                # after a step of a few decimetres the location Hessian (metres of sigma) has hardly
                # changed: the last factorisation serves (a chord step, triangular solves only)
                chord = True
            dx = solve_with_factor(factor, -g)
        except LinAlgError:
            return None, step
        x = x + dx
        size = float(np.max(np.abs(dx.reshape(-1, 6)[:, :step_axes])))
        if size <= step_tol_m:
            return x, step
        if chord and len(free) and size > 0.5 * last:
            factor = None  # the chord steps do not contract fast: back to Newton steps
        last = size
    return None, max_steps


def solve_local_newton(
    terms: T.Terms,
    x0: np.ndarray,
    fixed: np.ndarray | None = None,
    max_steps: int = 8,
    step_tol_m: float = 0.02,
    linearisation: WindowModel | None = None,
    cost_before: dict[str, float] | None = None,
    step_axes: int = 3,
    chord_after_m: float | None = None,
) -> tuple[np.ndarray, SolverResult] | None:
    """Newton steps from a warm start with only the location term re-linearised (one more edit).

    After one more edit the solution moves by metres but every orientation by well under a
    milliradian, so the relative, gravity and user terms are linearised once at ``x0``
    (their Gauss-Newton model is then exact to (1e-3 rad)^2, far below a millimetre) and
    only the robust location term, whose re-weighting is the real non-linearity, is
    re-evaluated at each step.  Each step solves

        (H_c + H_loc(x)) dx = -(g_c + H_c (x - x_lin) + g_loc(x))

    with ``H_c, g_c`` the banded normal equations of the other terms at ``x_lin`` (packed once)
    and ``g_loc, H_loc`` the location term's gradient and Newton Hessian
    (``terms.location_model``), until a step moves no position by more than ``step_tol_m``;
    the steps shrink by a factor of 20 or more each near the optimum, so the answer is then
    within about a millimetre of it.  Once a step is under ``CHORD_AFTER_STEPS`` tolerances
    (60 cm), the next ones re-use the last factorisation (chord steps: triangular solves only):
    the Hessian of a location term with metres of sigma hardly changes over such a step, so
    they contract about as fast (answers within 0.05 mm of pure Newton steps on the
    benchmark's runs); should one not halve the step, Newton steps resume.  Should the orientations have moved by more than a
    milliradian from x_lin after all, the other terms are linearised again there and the
    steps go on.  The true cost is evaluated once at the end.

    ``linearisation`` (``Linearisation.window`` over these keyframes; its x_lin may differ from
    x0, e.g. the solved run before one more edit): then nothing is linearised at x0, only the
    user terms are added to it (and relative-translation edges re-weighted).
    ``cost_before`` (the costs at x0, per term) saves evaluating them when known.
    ``step_axes`` 2: a step's size is measured east/north only (for a caller that reads the
    horizontal answer alone: without a location term the height of a long run is pinned by
    a hair of damping only, and round-off moves it by centimetres at every step).
    ``chord_after_m``: chord steps once a step is under this many metres (default
    ``CHORD_AFTER_STEPS`` step tolerances; np.inf: from the second step on, Newton steps
    again only where one does not halve the last).

    Returns None when the steps do not settle within ``max_steps`` or do not lower the
    cost (a far start: use ``solve_banded``).  ``fixed`` holds keyframes at ``x0``.
    """
    started = time.perf_counter()
    x = np.array(x0, dtype=float, copy=True)
    before = cost_before
    steps = 0
    for _outer in range(3):
        if linearisation is not None:
            x_lin, ab_c, g_c = _model_from_linearisation(terms, linearisation)
            linearisation = None
            if before is None:
                before = T.evaluate(terms, x, with_jac=False).costs()
        else:
            x_lin = x.copy()
            # the location term's Jacobian is not needed: it is re-modelled at every step
            ev = T.add_jacobians(terms, T.evaluate(terms, x_lin, with_jac=False), location=False)
            if before is None:
                before = ev.costs()
            D, U, g_c = T.normal_equations(terms, ev, location=False)
            ab_c = np.asfortranarray(pack_banded(D, U))
        x, n = _newton_on_model(terms, ab_c, g_c, x_lin, x, fixed, max_steps - steps, step_tol_m, step_axes,
                                chord_after_m)
        if x is None:
            return None
        steps += n
        # the other terms were linearised at x_lin: fine while orientations moved by well under
        # a milliradian (the usual case); otherwise linearise again where we are and go on
        if float(np.max(np.abs((x - x_lin).reshape(-1, 6)[:, 3:]), initial=0.0)) < 1e-3:
            break
    else:
        return None
    after = T.evaluate(terms, x, with_jac=False).costs()
    F0, F = sum(before.values()), sum(after.values())
    if not np.isfinite(F) or F > F0 * (1.0 + 1e-12):
        return None
    return x, SolverResult(
        status="converged",
        message=f"{steps} Newton steps (location term re-linearised), last step below {step_tol_m:g} m",
        iterations=steps,
        cost_before=before,
        cost_after=after,
        time_s=time.perf_counter() - started,
        method="local-newton",
    )
