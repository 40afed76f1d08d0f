"""The five terms of the correction problem, each beside its Jacobian.

State.  Keyframe i has a position ``p_i`` (ENU metres) and an orientation
``R_i = R~_i Exp(theta_i)``: a rotation vector ``theta_i`` (radians, body frame) that
perturbs the reported orientation on the right.  The state vector interleaves
``x = [p_0, theta_0, p_1, theta_1, ...]`` (6 per keyframe) so terms that link only
neighbouring keyframes give a block-banded Jacobian (band of 12 columns).  ``theta = 0``
is the reported orientation; corrections are small (gravity pins roll and pitch, yaw moves
by degrees at most) so this chart never approaches its singularity at |theta| = pi.

Residuals are whitened (divided by their sigma), so the cost is
``F(x) = 1/2 sum_i rho(|e_loc,i|^2) + 1/2 sum |r_user|^2 + 1/2 sum |r_RT|^2 + 1/2 sum |r_RR|^2 + 1/2 sum |r_G|^2``
with ``rho`` the robust loss of the location term, applied per keyframe to the whole
whitened 3-vector (as GTSAM's robust noise model does).  To keep one plain least-squares
problem for both solvers the location residual is rewritten exactly as
``r = sqrt(rho(s)/s) e`` with ``s = |e|^2``, so ``|r|^2 = rho(s)``; its Jacobian is
``dr/de = f I + 2 f'(s) e e^T`` with ``f = sqrt(rho(s)/s)``.

Terms (``p~, R~`` reported, ``p, R`` corrected):

* location      ``e_i = W_i (p_i - g_i)``                                  (3 per located keyframe)
* user          ``r_k = W_k (p_k - c_k)``  (vertical weight 0 for a 2-D edit)  (3 per edit)
* rel. transl.  ``r_ij = (R_i^T (p_j - p_i) - D_ij) / s_RT,ij``, ``D_ij = R~_i^T (p~_j - p~_i)``
* rel. rotation ``r_ij = Log(dR~_ij^T R_i^T R_j) / s_RR,ij``, ``dR~_ij = R~_i^T R~_j``
* gravity       ``r_i = (R_i^T z - R~_i^T z) / s_G``, ``z = [0, 0, 1]``

with j = i + 1.  Jacobians, using ``Exp(theta + d) ~= Exp(theta) Exp(Jr(theta) d)``:

* d(R_i^T v)/d theta_i = [R_i^T v]x Jr(theta_i)
* d Log(E)/d theta_j = Jr^-1(phi) Jr(theta_j);  d Log(E)/d theta_i = -Jl^-1(phi) dR~^T Jr(theta_i)
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

from posefix.core import rotations as rot

LOSSES = ("none", "huber", "soft_l1", "cauchy")
TERM_NAMES = ("location", "user", "relative_translation", "relative_rotation", "gravity")


@dataclass(frozen=True)
class Terms:
    """Data of every term on k keyframes (relative terms link i and i + 1).

    p_rep_m (k,3), R_rep (k,3,3): reported poses.
    loc_idx (m,), loc_g_m (m,3), loc_w (m,3): located keyframes, measured positions, 1/sigma per axis.
    user_idx (u,), user_c_m (u,3), user_w (u,3): edited keyframes, targets, 1/sigma (0 = free axis).
    rel_delta_m (k-1,3), rel_w_t (k-1,): body-frame steps D_ij and 1/s_RT.
    rel_dR (k-1,3,3), rel_w_r (k-1,): reported relative rotations and 1/s_RR; rel_dq (k-1,4) the same as quaternions.
    grav_zb (k,3), grav_w (k,): reported body-frame up vectors and 1/s_G.
    """

    p_rep_m: np.ndarray
    R_rep: np.ndarray
    loc_idx: np.ndarray
    loc_g_m: np.ndarray
    loc_w: np.ndarray
    user_idx: np.ndarray
    user_c_m: np.ndarray
    user_w: np.ndarray
    rel_delta_m: np.ndarray
    rel_w_t: np.ndarray
    rel_dR: np.ndarray
    rel_w_r: np.ndarray
    rel_dq: np.ndarray
    grav_zb: np.ndarray
    grav_w: np.ndarray
    loss: str = "cauchy"
    loss_scale: float = 1.0

    @property
    def n_keyframes(self) -> int:
        return len(self.p_rep_m)


def build_terms(
    p_rep_m: np.ndarray,
    q_rep_wxyz: np.ndarray,
    loc_idx: np.ndarray,
    loc_g_m: np.ndarray,
    loc_sigma_m: np.ndarray,
    user_idx: np.ndarray,
    user_c_m: np.ndarray,
    user_sigma_m: np.ndarray,
    sigma_rt_m: np.ndarray,
    sigma_rr_rad: np.ndarray,
    sigma_g: float | np.ndarray,
    loss: str = "cauchy",
    loss_scale: float = 1.0,
) -> Terms:
    """Terms from reported keyframe poses and sigmas (inf sigma = axis not constrained)."""
    if loss not in LOSSES:
        raise ValueError(f"loss must be one of {LOSSES}, got {loss!r}")
    p_rep_m = np.asarray(p_rep_m, dtype=float)
    q_rep = rot.normalize_quat(q_rep_wxyz)
    R_rep = rot.quat_to_matrix(q_rep)
    k = len(p_rep_m)
    delta = np.einsum("kji,kj->ki", R_rep[:-1], p_rep_m[1:] - p_rep_m[:-1])
    dR = np.einsum("kji,kjl->kil", R_rep[:-1], R_rep[1:])
    return Terms(
        p_rep_m=p_rep_m,
        R_rep=R_rep,
        loc_idx=np.asarray(loc_idx, dtype=np.int64),
        loc_g_m=np.asarray(loc_g_m, dtype=float).reshape(-1, 3),
        loc_w=1.0 / np.asarray(loc_sigma_m, dtype=float).reshape(-1, 3),
        user_idx=np.asarray(user_idx, dtype=np.int64),
        user_c_m=np.asarray(user_c_m, dtype=float).reshape(-1, 3),
        user_w=1.0 / np.asarray(user_sigma_m, dtype=float).reshape(-1, 3),
        rel_delta_m=delta,
        rel_w_t=1.0 / np.broadcast_to(np.asarray(sigma_rt_m, dtype=float), (k - 1,)),
        rel_dR=dR,
        rel_w_r=1.0 / np.broadcast_to(np.asarray(sigma_rr_rad, dtype=float), (k - 1,)),
        rel_dq=rot.quat_multiply(rot.quat_conjugate(q_rep[:-1]), q_rep[1:]),
        grav_zb=R_rep[:, 2, :].copy(),
        grav_w=1.0 / np.broadcast_to(np.asarray(sigma_g, dtype=float), (k,)),
        loss=loss,
        loss_scale=float(loss_scale),
    )


RAYLEIGH_MEDIAN = 1.1774  # median of the length of a 2-D vector of unit-sigma Gaussians
MISALIGNMENT_MIN_STEPS = 10  # forward steps needed to estimate how the pose's frame sits in the vehicle


def sideways_steps(rel_delta_m: np.ndarray, rel_dR: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Reported steps in the mid-step body frame (k-1,3), half relative rotations (k-1,3) and
    the sideways/vertical motion a vehicle would have made (k-1,2), metres.

    A vehicle turning at a steady rate moves along the chord, whose direction is the heading
    half-way through the turn: ``s_ij = Exp(-phi/2) D_ij`` with ``phi = Log(dR~_ij)``.  Measured
    in the frame of keyframe i instead, a 90 degree corner taken in 4 s would show 1-2 m of
    false sideways motion per second.  The pose's body frame is often the sensor's, mounted at
    a small fixed angle to the vehicle (a dashboard device pitched down 4 degrees shows 1.2 m/s
    of "vertical" motion at 17 m/s): that misalignment makes sideways/vertical motion
    proportional to forward motion, so the run's median ratio (over steps moving forward by
    more than a metre) is taken out first.  What is left, left and up, is what a road vehicle
    cannot do beyond side slip and bumps.
    """
    half = 0.5 * rot.log_matrix(rel_dR)
    s = np.einsum("kij,kj->ki", rot.exp_matrix(-half), rel_delta_m)
    fwd = s[:, 0] > 1.0
    m = np.zeros(2)
    if np.count_nonzero(fwd) >= MISALIGNMENT_MIN_STEPS:
        m = np.median(s[fwd, 1:] / s[fwd, :1], axis=0)
    return s, half, s[:, 1:] - s[:, :1] * m


def vehicle_motion(rel_delta_m: np.ndarray, rel_dR: np.ndarray, dt_s: np.ndarray, max_speed_mps: float):
    """Non-holonomic check of the reported steps: (plausible steps D' (k-1,3), excess (k-1,) m).

    A road vehicle does not slide sideways or jump vertically faster than ``max_speed_mps``
    (side slip and bumps stay well below 0.5 m/s).  The part of a reported step's sideways
    and vertical motion (see ``sideways_steps``) beyond ``max_speed_mps * dt`` is not motion
    but a jump of the pose's error (an INS following an urban-canyon GNSS offset), so the
    relative term measures the step without it (that part scaled down to the limit) and its
    sigma grows by the excess removed (how much was really error is not known).  Where the
    attitude itself jitters, the limit rises to 4 sigmas of the run's own sideways motion.
    ``max_speed_mps`` 0: steps unchanged.
    """
    k1 = len(rel_delta_m)
    if max_speed_mps <= 0 or k1 == 0:
        return rel_delta_m, np.zeros(k1)
    s, half, side_yz = sideways_steps(rel_delta_m, rel_dR)
    side = np.hypot(side_yz[:, 0], side_yz[:, 1])
    dt_s = np.asarray(dt_s, dtype=float)
    # an attitude that jitters (a cheap IMU, a heading derived from a noisy track) shows sideways
    # motion of its own: only what stands out of it (4 sigmas of its Rayleigh spread) is read as a jump
    noise_mps = float(np.median(side / np.maximum(dt_s, 1e-9))) / RAYLEIGH_MEDIAN
    limit = max(max_speed_mps, 4.0 * noise_mps) * dt_s
    excess = np.maximum(side - limit, 0.0)
    hit = excess > 0
    if not np.any(hit):
        return rel_delta_m, excess
    s_hit = s[hit].copy()
    s_hit[:, 1:] -= side_yz[hit] * (excess[hit] / side[hit])[:, None]  # cut to the limit, misalignment kept
    out = rel_delta_m.copy()
    out[hit] = np.einsum("kij,kj->ki", rot.exp_matrix(half[hit]), s_hit)
    return out, excess


def window_terms(terms: Terms, a: int, b: int) -> Terms:
    """The terms that touch only keyframes a..b (inclusive), re-indexed from 0."""
    loc = (terms.loc_idx >= a) & (terms.loc_idx <= b)
    usr = (terms.user_idx >= a) & (terms.user_idx <= b)
    return dataclasses.replace(
        terms,
        p_rep_m=terms.p_rep_m[a:b + 1], R_rep=terms.R_rep[a:b + 1],
        loc_idx=terms.loc_idx[loc] - a, loc_g_m=terms.loc_g_m[loc], loc_w=terms.loc_w[loc],
        user_idx=terms.user_idx[usr] - a, user_c_m=terms.user_c_m[usr], user_w=terms.user_w[usr],
        rel_delta_m=terms.rel_delta_m[a:b], rel_w_t=terms.rel_w_t[a:b], rel_dR=terms.rel_dR[a:b],
        rel_w_r=terms.rel_w_r[a:b], rel_dq=terms.rel_dq[a:b],
        grav_zb=terms.grav_zb[a:b + 1], grav_w=terms.grav_w[a:b + 1],
    )


def same_array(a: np.ndarray, b: np.ndarray) -> bool:
    """Whether two arrays hold the same values (the same object: at once)."""
    return a is b or (a.shape == b.shape and bool(np.array_equal(a, b)))


def changed_keyframes(new: Terms, old: Terms, tol_m: float = 1e-3, tol_rel: float = 1e-3) -> np.ndarray | None:
    """(k,) bool: keyframes whose location or user terms differ between two problems on the
    same keyframes, or whose relative or gravity terms were re-weighted (by more than ``tol_rel``)
    (None when they cannot be compared: other keyframes, located set or reported steps)."""
    k = new.n_keyframes
    if old.n_keyframes != k or not np.array_equal(new.loc_idx, old.loc_idx):
        return None
    if not same_array(new.rel_delta_m, old.rel_delta_m):
        return None  # other reported steps (the first edit of a run measures them without sideways jumps)
    out = np.zeros(k, dtype=bool)
    moved = np.any(np.abs(new.loc_g_m - old.loc_g_m) > tol_m, axis=1)
    rew = np.any(np.abs(new.loc_w - old.loc_w) > tol_rel * np.abs(old.loc_w), axis=1)
    out[new.loc_idx[moved | rew]] = True
    # relative terms re-weighted (edits the reported shape cannot join loosen them): both ends
    for w_new, w_old in ((new.rel_w_t, old.rel_w_t), (new.rel_w_r, old.rel_w_r)):
        if w_new is not w_old:
            rel = np.flatnonzero(np.abs(w_new - w_old) > tol_rel * np.abs(w_old))
            out[rel] = True
            out[rel + 1] = True
    if new.grav_w is not old.grav_w:
        out |= np.abs(new.grav_w - old.grav_w) > tol_rel * np.abs(old.grav_w)
    # user terms: an edit added or removed, or moved / re-weighted (vectorised over the edits)
    both = np.intersect1d(new.user_idx, old.user_idx)
    out[np.setxor1d(new.user_idx, old.user_idx)] = True
    if len(both):
        o_new = np.argsort(new.user_idx, kind="stable")
        o_old = np.argsort(old.user_idx, kind="stable")
        i_new = o_new[np.searchsorted(new.user_idx[o_new], both)]
        i_old = o_old[np.searchsorted(old.user_idx[o_old], both)]
        c0, w0 = old.user_c_m[i_old], old.user_w[i_old]
        c1, w1 = new.user_c_m[i_new], new.user_w[i_new]
        with np.errstate(invalid="ignore"):
            moved_u = np.any(np.abs(c1 - c0) * np.minimum(w0, w1) > 1e-6, axis=1) | np.any(w1 != w0, axis=1)
        out[both[moved_u]] = True
    return out


# ----------------------------------------------------------------------------- robust loss


def loss_ratio(z: np.ndarray, loss: str) -> tuple[np.ndarray, np.ndarray]:
    """g(z) = rho0(z)/z and g'(z) for the unit-scale losses of scipy.optimize.least_squares.

    rho0: none z; huber z (z<=1) else 2 sqrt(z) - 1; soft_l1 2 (sqrt(1+z) - 1); cauchy log(1+z).
    """
    z = np.asarray(z, dtype=float)
    if loss == "none":
        return np.ones_like(z), np.zeros_like(z)
    if loss == "huber":
        big = z > 1.0
        zs = np.where(big, z, 1.0)
        sq = np.sqrt(zs)
        return np.where(big, (2.0 * sq - 1.0) / zs, 1.0), np.where(big, (1.0 - sq) / (zs * zs), 0.0)
    if loss == "soft_l1":
        sq = np.sqrt(1.0 + z)
        return 2.0 / (sq + 1.0), -1.0 / ((sq + 1.0) ** 2 * sq)
    if loss == "cauchy":
        small = z < 1e-4
        zs = np.where(small, 1.0, z)
        lg = np.log1p(zs)
        g = np.where(small, 1.0 - z / 2.0 + z * z / 3.0, lg / zs)
        dg = np.where(small, -0.5 + 2.0 * z / 3.0, (zs / (1.0 + zs) - lg) / (zs * zs))
        return g, dg
    raise ValueError(f"unknown loss {loss!r}")


def loss_derivatives(z: np.ndarray, loss: str) -> tuple[np.ndarray, np.ndarray]:
    """rho0'(z) and rho0''(z) of the unit-scale losses."""
    z = np.asarray(z, dtype=float)
    if loss == "none":
        return np.ones_like(z), np.zeros_like(z)
    if loss == "huber":
        big = z > 1.0
        zs = np.where(big, z, 1.0)
        return np.where(big, zs**-0.5, 1.0), np.where(big, -0.5 * zs**-1.5, 0.0)
    if loss == "soft_l1":
        return (1.0 + z) ** -0.5, -0.5 * (1.0 + z) ** -1.5
    if loss == "cauchy":
        return 1.0 / (1.0 + z), -1.0 / (1.0 + z) ** 2
    raise ValueError(f"unknown loss {loss!r}")


def robust_cost(s: np.ndarray, loss: str, scale: float) -> np.ndarray:
    """rho(s) = C^2 rho0(s / C^2) for whitened squared distances s."""
    c2 = scale * scale
    g, _ = loss_ratio(s / c2, loss)
    return g * s


# ----------------------------------------------------------------------------- residuals


@dataclass
class Evaluation:
    """Residuals (and Jacobian blocks) of every term at one state.

    Blocks are (m, 3, 3) matrices: d residual / d p or d theta of the keyframe named.
    ``cache`` keeps the intermediate quantities the Jacobians reuse.
    """

    loc_r: np.ndarray
    user_r: np.ndarray
    rt_r: np.ndarray
    rr_r: np.ndarray
    grav_r: np.ndarray
    jac: dict[str, np.ndarray] = field(default_factory=dict)
    cache: dict[str, np.ndarray] = field(default_factory=dict)

    def costs(self) -> dict[str, float]:
        """Cost of each term, 1/2 sum of squared (robustified) residuals."""
        return {
            name: 0.5 * float(np.einsum("ij,ij->", r, r))
            for name, r in zip(TERM_NAMES, (self.loc_r, self.user_r, self.rt_r, self.rr_r, self.grav_r))
        }

    def cost(self) -> float:
        return float(sum(self.costs().values()))

    def residual_vector(self) -> np.ndarray:
        return np.concatenate([r.ravel() for r in (self.loc_r, self.user_r, self.rt_r, self.rr_r, self.grav_r)])


def split_state(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """State (6k,) -> positions (k,3) metres and rotation vectors (k,3) radians."""
    x = np.asarray(x, dtype=float).reshape(-1, 6)
    return x[:, :3], x[:, 3:]


def initial_state(terms: Terms) -> np.ndarray:
    """The reported poses: p = p~, theta = 0."""
    x = np.zeros((terms.n_keyframes, 6))
    x[:, :3] = terms.p_rep_m
    return x.ravel()


def _log_unit_quat(q: np.ndarray) -> np.ndarray:
    """Rotation vectors of unit quaternions (no renormalisation; the short way round)."""
    w = q[:, 0]
    v = q[:, 1:] * np.where(w < 0, -1.0, 1.0)[:, None]
    w = np.abs(w)
    s = np.sqrt(np.einsum("ij,ij->i", v, v))
    small = s < 1e-8
    k = np.where(small, 2.0 / np.maximum(w, 1e-300), 2.0 * np.arctan2(s, w) / np.where(small, 1.0, s))
    return k[:, None] * v


def location_residual(terms: Terms, p_m: np.ndarray):
    """Robustified location residual r = sqrt(rho(s)/s) e with e = W (p - g); returns r, e, s."""
    e = terms.loc_w * (p_m[terms.loc_idx] - terms.loc_g_m)
    s = np.einsum("mi,mi->m", e, e)
    g, _ = loss_ratio(s / terms.loss_scale**2, terms.loss)
    return np.sqrt(g)[:, None] * e, e, s


def location_jacobian(terms: Terms, e: np.ndarray, s: np.ndarray) -> np.ndarray:
    """dr/dp of the robustified location residual: (f I + 2 f'(s) e e^T) W, f = sqrt(rho(s)/s)."""
    c2 = terms.loss_scale**2
    g, dg = loss_ratio(s / c2, terms.loss)
    f = np.sqrt(g)
    df = dg / (2.0 * f * c2)  # f'(s) = g'(z) / (2 f C^2)
    dr_de = f[:, None, None] * np.eye(3) + (2.0 * df)[:, None, None] * (e[:, :, None] * e[:, None, :])
    return dr_de * terms.loc_w[:, None, :]


def location_model(terms: Terms, p_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Gradient (m,3) and solver Hessian (m,3,3) of 1/2 rho(|e|^2) w.r.t. each located position.

    Gradient ``W rho'(s) e`` (equal to ``J^T r`` of the rewritten residual); Hessian as in
    ``location_hessian``.  Used by the local Newton solve, which re-linearises only this term.
    """
    e = terms.loc_w * (p_m[terms.loc_idx] - terms.loc_g_m)
    s = np.einsum("mi,mi->m", e, e)
    c2 = terms.loss_scale**2
    d1, d2 = loss_derivatives(s / c2, terms.loss)
    along = np.maximum(d1 + 2.0 * d2 * s / c2, 0.1 * d1)
    u = e / np.sqrt(np.maximum(s, 1e-300))[:, None]
    uu = u[:, :, None] * u[:, None, :]
    M = d1[:, None, None] * (np.eye(3) - uu) + along[:, None, None] * uu
    return terms.loc_w * (d1[:, None] * e), M * terms.loc_w[:, :, None] * terms.loc_w[:, None, :]


def location_hessian(terms: Terms, p_m: np.ndarray) -> np.ndarray:
    """Second-order model of 1/2 rho(|e|^2) for the solver, (m,3,3) per located keyframe.

    ``W (rho' I + 2 rho'' e e^T) W`` (the exact Hessian of the loss, e being linear in p),
    with the curvature along e clipped at 10 % of rho' where the loss turns concave (the tail
    of Cauchy): a Newton model of the robust loss converges in a few steps where the
    Gauss-Newton model of the rewritten residual crawls.
    """
    return location_model(terms, p_m)[1]


def evaluate(terms: Terms, x: np.ndarray, with_jac: bool = True) -> Evaluation:
    """All residuals at state x (6k,), with Jacobian blocks when ``with_jac``.

    Residuals, in the order of ``TERM_NAMES`` (see the module docstring for equations):
    location ``sqrt(rho(s)/s) W (p_i - g_i)``; user ``W (p_k - c_k)``; relative translation
    ``w (R_i^T (p_j - p_i) - D_ij)``; relative rotation ``w Log(dq~^-1 q_i^-1 q_j)`` computed
    with quaternions (``q_i = q~_i Exp(theta_i)``); gravity ``w (R_i^T z - R~_i^T z)``.
    """
    p_m, theta = split_state(x)
    q_corr = rot.exp_quat(theta)  # Exp(theta_i)
    R = terms.R_rep @ rot.quat_to_matrix(q_corr)
    loc_r, e, s = location_residual(terms, p_m)
    user_r = terms.user_w * (p_m[terms.user_idx] - terms.user_c_m)
    b = np.einsum("kji,kj->ki", R[:-1], p_m[1:] - p_m[:-1])  # R_i^T (p_j - p_i)
    rt_r = terms.rel_w_t[:, None] * (b - terms.rel_delta_m)
    # E = dR~^T Exp(-theta_i) dR~ Exp(theta_j) as a quaternion product
    dq = terms.rel_dq
    qE = rot.quat_multiply(
        rot.quat_multiply(rot.quat_conjugate(dq), rot.quat_conjugate(q_corr[:-1])),
        rot.quat_multiply(dq, q_corr[1:]),
    )
    phi = _log_unit_quat(qE)
    rr_r = terms.rel_w_r[:, None] * phi
    zb = R[:, 2, :]
    grav_r = terms.grav_w[:, None] * (zb - terms.grav_zb)
    ev = Evaluation(loc_r, user_r, rt_r, rr_r, grav_r,
                    cache={"p": p_m, "theta": theta, "R": R, "e": e, "s": s, "b": b, "phi": phi, "zb": zb})
    if with_jac:
        add_jacobians(terms, ev)
    return ev


def add_jacobians(terms: Terms, ev: Evaluation, location: bool = True) -> Evaluation:
    """Fill ``ev.jac`` with every Jacobian block at the state ``ev`` was evaluated at.

    ``location=False`` leaves out the location blocks (the local Newton solve models that
    term itself at every step, so computing them would be wasted).

    * location: ``dr/dp`` (see ``location_jacobian``) and the solver's loss Hessian
    * user: ``diag(W)``
    * relative translation: ``-w R_i^T``, ``w R_i^T``, ``w [R_i^T (p_j - p_i)]x Jr(theta_i)``
    * relative rotation: ``-w Jl^-1(phi) dR~^T Jr(theta_i)``, ``w Jr^-1(phi) Jr(theta_j)``
    * gravity: ``w [R_i^T z]x Jr(theta_i)``
    """
    c = ev.cache
    R, theta = c["R"], c["theta"]
    Jr = rot.right_jacobian(theta)
    wt = terms.rel_w_t[:, None, None]
    wr = terms.rel_w_r[:, None, None]
    RiT = np.swapaxes(R[:-1], 1, 2) * wt
    user_J = np.zeros((len(ev.user_r), 3, 3))
    user_J[:, [0, 1, 2], [0, 1, 2]] = terms.user_w
    dRt = np.swapaxes(terms.rel_dR, 1, 2)
    Jr_inv, Jl_inv = rot.jacobian_inverses(c["phi"])
    ev.jac = {
        "user_p": user_J,
        "rt_pi": -RiT,
        "rt_pj": RiT,
        "rt_ti": rot.skew(c["b"]) @ Jr[:-1] * wt,
        "rr_ti": -(Jl_inv @ dRt @ Jr[:-1]) * wr,
        "rr_tj": (Jr_inv @ Jr[1:]) * wr,
        "g_t": rot.skew(c["zb"]) @ Jr * terms.grav_w[:, None, None],
    }
    if location:
        ev.jac["loc_H"] = location_hessian(terms, c["p"])
        ev.jac["loc_p"] = location_jacobian(terms, c["e"], c["s"])
    return ev


def cost(terms: Terms, x: np.ndarray) -> float:
    """F(x), the total cost."""
    return evaluate(terms, x, with_jac=False).cost()


# ----------------------------------------------------------------------------- assembly


def _block_entries(res_offset: int, n_res: int, var_block: np.ndarray, var_offset: int, J: np.ndarray):
    """COO rows/cols/values of (n_res, 3, 3) blocks placed at residual rows and variable columns."""
    m = len(J)
    rows = res_offset + np.arange(m)[:, None, None] * 3 + np.arange(3)[None, :, None]
    cols = var_block[:, None, None] * 6 + var_offset + np.arange(3)[None, None, :]
    rows = np.broadcast_to(rows, (m, 3, 3))
    cols = np.broadcast_to(cols, (m, 3, 3))
    return rows.ravel(), cols.ravel(), J.ravel()


def sparse_jacobian(terms: Terms, ev: Evaluation):
    """The full Jacobian as a scipy CSR matrix, shape (n_residuals, 6k)."""
    from scipy.sparse import csr_matrix

    k = terms.n_keyframes
    ar = np.arange(k)
    sizes = [ev.loc_r.size, ev.user_r.size, ev.rt_r.size, ev.rr_r.size, ev.grav_r.size]
    off = np.concatenate([[0], np.cumsum(sizes)])
    parts = [
        _block_entries(off[0], sizes[0], terms.loc_idx, 0, ev.jac["loc_p"]),
        _block_entries(off[1], sizes[1], terms.user_idx, 0, ev.jac["user_p"]),
        _block_entries(off[2], sizes[2], ar[:-1], 0, ev.jac["rt_pi"]),
        _block_entries(off[2], sizes[2], ar[1:], 0, ev.jac["rt_pj"]),
        _block_entries(off[2], sizes[2], ar[:-1], 3, ev.jac["rt_ti"]),
        _block_entries(off[3], sizes[3], ar[:-1], 3, ev.jac["rr_ti"]),
        _block_entries(off[3], sizes[3], ar[1:], 3, ev.jac["rr_tj"]),
        _block_entries(off[4], sizes[4], ar, 3, ev.jac["g_t"]),
    ]
    rows = np.concatenate([p[0] for p in parts])
    cols = np.concatenate([p[1] for p in parts])
    vals = np.concatenate([p[2] for p in parts])
    return csr_matrix((vals, (rows, cols)), shape=(int(off[-1]), 6 * k))


def normal_equations(
    terms: Terms, ev: Evaluation, location: bool = True
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """J^T J as diagonal blocks D (k,6,6) and upper off-diagonal blocks U (k-1,6,6), and J^T r (6k,).

    U[i] couples keyframe i (rows) with keyframe i + 1 (columns).  ``location=False`` leaves
    the location term out (the local Newton solve adds it itself at every step).
    """
    k = terms.n_keyframes
    D = np.zeros((k, 6, 6))
    U = np.zeros((max(k - 1, 0), 6, 6))
    g = np.zeros((k, 6))
    jac = ev.jac
    # (batched 3x3 products by matmul: numpy's einsum takes about 4x as long over them)

    def ata(A, B):
        return np.swapaxes(A, 1, 2) @ B

    Dflat = D.reshape(k, 36)  # a block's diagonal entries: 0, 7, 14 (position), 21, 28, 35
    # location and user: position blocks only
    # (each keyframe has at most one location and one user term, so fancy-index adds are safe)
    if location:
        D[terms.loc_idx, :3, :3] += jac["loc_H"] if "loc_H" in jac else ata(jac["loc_p"], jac["loc_p"])
        g[terms.loc_idx, :3] += np.einsum("mri,mr->mi", jac["loc_p"], ev.loc_r)
    # the user Jacobian is diag(W): J^T J = W^2, J^T r = W r
    uw = terms.user_w
    np.add.at(Dflat, (terms.user_idx[:, None], np.array([0, 7, 14])[None, :]), uw * uw)
    g[terms.user_idx, :3] += np.einsum("mri,mr->mi", jac["user_p"], ev.user_r)
    Gt = jac["g_t"]
    if k > 1:
        # Edge blocks, exploiting their structure: the relative-translation rows are
        # [P, T, -P, 0] over (p_i, theta_i, p_j, theta_j) with P = -w R_i^T (so P^T P = w^2 I),
        # the relative-rotation rows [0, A, 0, B].
        P, Tt = jac["rt_pi"], jac["rt_ti"]
        A, B = jac["rr_ti"], jac["rr_tj"]
        PtT = ata(P, Tt)
        PtT_t = np.swapaxes(PtT, 1, 2)
        w2 = terms.rel_w_t**2
        Uflat = U.reshape(k - 1, 36)
        for d in (0, 7, 14):
            Dflat[:-1, d] += w2
            Dflat[1:, d] += w2
            Uflat[:, d] -= w2
        # the orientation blocks summed contiguously, then written once each (D and U hold
        # nothing there yet: the location and user terms touch positions only)
        Drr = ata(Gt, Gt)
        Drr[:-1] += ata(Tt, Tt)
        Drr[:-1] += ata(A, A)
        Drr[1:] += ata(B, B)
        D[:, 3:, 3:] = Drr
        D[:-1, :3, 3:] = PtT
        D[:-1, 3:, :3] = PtT_t
        U[:, 3:, :3] = -PtT_t
        U[:, 3:, 3:] = ata(A, B)
        Ptr = np.einsum("mri,mr->mi", P, ev.rt_r)
        g[:-1, :3] += Ptr
        g[1:, :3] -= Ptr
        g[:-1, 3:] += np.einsum("mri,mr->mi", Tt, ev.rt_r) + np.einsum("mri,mr->mi", A, ev.rr_r)
        g[1:, 3:] += np.einsum("mri,mr->mi", B, ev.rr_r)
    else:
        D[:, 3:, 3:] = ata(Gt, Gt)
    g[:, 3:] += np.einsum("mri,mr->mi", Gt, ev.grav_r)
    return D, U, g.ravel()


def implausible_motion_m(p_enu_m: np.ndarray, q_wxyz: np.ndarray, dt_s: np.ndarray, max_speed_mps: float) -> np.ndarray:
    """(k-1,) sideways and vertical motion between keyframes beyond what a vehicle can do, metres.

    A road vehicle does not slide sideways or jump vertically faster than ``max_speed_mps``
    (side slip and bumps stay well below 0.5 m/s).  A reported step with more body-frame
    lateral/vertical motion than that carries a jump of the pose's error (an INS following
    an urban-canyon GNSS offset); its relative-translation sigma grows by the excess so the
    correction can undo the jump there rather than smear it over the whole interval.
    0 disables the check (pedestrians, handheld devices).
    """
    if max_speed_mps <= 0 or len(p_enu_m) < 2:
        return np.zeros(max(len(p_enu_m) - 1, 0))
    R = rot.quat_to_matrix(rot.normalize_quat(q_wxyz))
    delta = np.einsum("kji,kj->ki", R[:-1], np.diff(p_enu_m, axis=0))
    dR = np.einsum("kji,kjl->kil", R[:-1], R[1:])
    return vehicle_motion(delta, dR, dt_s, max_speed_mps)[1]  # measured half-way through the step
