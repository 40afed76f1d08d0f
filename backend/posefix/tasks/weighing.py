"""Weighing a run's submissions by what is known of their operators: gold-run accuracy, and
agreement with others on the task's shared runs (``posefix.tasks.fusion`` does the numbers).

One ``Weighing`` serves the consensus (which submissions are off it, held from
auto-approval), the merge (the fused positions, and whether the merge is safe) and the
review screen (rank, weight, measured accuracy beside distance).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from sqlalchemy.orm import Session

from posefix.core import geodesy
from posefix.tasks import fusion
from posefix.tasks import repository as repo
from posefix.tasks.consensus import geometric_median
from posefix.tasks.models import Assignment, AssignmentStatus, TaskRun
from posefix.tasks.states import local_m, run_origin

# A submission is off the consensus when its operator's measured accuracy explains its
# distance with probability below this (chi-square upper tail over its moved keyframes).
ALPHA = 1e-3
POOL_RUNS = 50  # the task's most recent shared runs the EM learns from
MIN_POSITIONS = 20  # shared-run positions that make an operator's agreement a measurement
# An operator never measured is expected to be as accurate as the median measured one, known
# to within a factor of about two: worth this many degrees of freedom in the test.
TYPICAL_DOF = 4.0


@dataclass
class Weighing:
    """ids (m,) assignment ids; x_m (m, k, 2) metres; valid (m, k); moved: keyframes anyone
    moved; sigma_m (m,) each operator's accuracy (per-axis, all evidence); sigma_ref_m (m,)
    measured elsewhere (None: never measured); accuracy_m / gold_scored from gold runs;
    fused over all keyframes; test on the moved keyframes; method "weighted" or
    "geometric_median" (nothing known yet)."""

    ids: list[int]
    origin: geodesy.EnuOrigin
    x_m: np.ndarray
    valid: np.ndarray
    moved: list[int]
    sigma_m: np.ndarray
    sigma_ref_m: np.ndarray
    measured: np.ndarray
    accuracy_m: list[float | None]
    gold_scored: list[int]
    fused: fusion.Fused
    test: fusion.ChiTest | None
    method: str

    @property
    def flagged(self) -> np.ndarray:
        if self.test is None:
            return np.zeros(len(self.ids), dtype=bool)
        return self.test.p < ALPHA

    @property
    def settled(self) -> bool:
        """Can the evidence tell which work is right? Yes when no one is off the consensus, or
        three or more agree (their spreads pair up: each one's scale follows from the run), or
        one of them was measured elsewhere (the others' scales follow from it). Two unmeasured
        operators who agree only against an outlier may be the accurate one and a careless one,
        and this run alone cannot say which."""
        off = self.flagged
        if not off.any():
            return True
        agree = ~off
        return int(agree.sum()) >= 3 or bool(np.any(self.measured[agree]))

    @property
    def weight_share(self) -> np.ndarray:
        """(m,) each submission's share of the fused estimate over the moved keyframes."""
        w = self.fused.w[:, self.moved].sum(axis=1) if self.moved else self.fused.w.sum(axis=1)
        total = w.sum()
        return w / total if total > 0 else np.full(len(self.ids), 1.0 / max(len(self.ids), 1))


def positions_m(subs: list[Assignment], origin: geodesy.EnuOrigin) -> tuple[np.ndarray, np.ndarray]:
    """(m, k, 2) positions in metres and (m, k) valid (False where deleted): where an operator
    placed a keyframe, the place they chose (the engine's solve pulls it back towards the
    input, and the merge solves again); elsewhere their corrected track."""
    pos = np.array([a.corrected for a in subs], dtype=float)
    for i, a in enumerate(subs):
        es = a.edit_set or {}
        own = {int(k) for k in es.get("own_moves", [])}
        for m in es.get("moves", []):
            if int(m[0]) in own and 0 <= int(m[0]) < pos.shape[1]:
                pos[i, int(m[0])] = (m[1], m[2])
    x_m = local_m(pos[..., 0], pos[..., 1], origin)
    valid = np.ones(x_m.shape[:2], dtype=bool)
    for i, a in enumerate(subs):
        for d in (a.edit_set or {}).get("deleted", []):
            if 0 <= int(d) < valid.shape[1]:
                valid[i, int(d)] = False
    return x_m, valid


def moved_keyframes(subs: list[Assignment]) -> list[int]:
    return sorted({int(m) for a in subs for m in (a.edit_set or {}).get("own_moves", [])})


def _obs(session: Session, subs: list[Assignment], op_index: dict[int, int], contributors: set[int],
         origin: geodesy.EnuOrigin | None = None) -> fusion.RunObs | None:
    moved = moved_keyframes(subs)
    if len(subs) < 2 or not moved:
        return None
    origin = origin or run_origin(session, subs[0].run_id)
    x_m, valid = positions_m(subs, origin)
    return fusion.RunObs(x_m[:, moved], valid[:, moved], np.array([op_index[a.operator_id or 0] for a in subs]),
                         np.array([a.id in contributors for a in subs]))


def weigh(session: Session, tr: TaskRun, subs: list[Assignment], contributors: set[int] | None = None) -> Weighing:
    """Weigh ``subs`` (evaluated submissions of ``tr``); only ``contributors`` pull the fused
    positions (default: all not rejected, less the work off the consensus, which waits for a
    reviewer)."""
    chosen = contributors is not None
    contributors = contributors if contributors is not None else {
        a.id for a in subs if a.status != AssignmentStatus.rejected}
    origin = run_origin(session, tr.run_id)
    x_m, valid = positions_m(subs, origin)
    moved = moved_keyframes(subs)
    pool = [rows for trid, rows in repo.evaluated_by_run(session, tr.task_id, POOL_RUNS).items() if trid != tr.id]
    users = sorted({a.operator_id or 0 for a in subs} | {a.operator_id or 0 for rows in pool for a in rows})
    op_index = {u: j for j, u in enumerate(users)}
    gold = repo.gold_accuracies(session, users)
    prior_s = np.array([fusion.sigma_from_mean_error(gold[u][0]) if u in gold else np.nan for u in users])
    prior_n = np.array([fusion.GOLD_POSITIONS * gold[u][1] if u in gold else 0.0 for u in users])
    others = [o for rows in pool if (o := _obs(session, rows, op_index, {a.id for a in rows
                                                                       if a.status != AssignmentStatus.rejected}))]
    # in the EM only a reviewer's rejection counts work wholly against its operator; work left
    # out of this merge (outweighed, or undecided) is still honest evidence of their accuracy
    here = _obs(session, subs, op_index, {a.id for a in subs if a.status != AssignmentStatus.rejected}, origin)
    ops = np.array([op_index[a.operator_id or 0] for a in subs])
    truth = np.array([a.id in contributors for a in subs])
    # measured elsewhere: gold runs and the task's other shared runs, never this run itself
    seen_elsewhere = np.zeros(len(users), dtype=bool)
    for o in others:
        seen_elsewhere[o.op] = True
    measured_ops = ~np.isnan(prior_s) | seen_elsewhere
    known = measured_ops[ops].any() or (here is not None and len(subs) >= 3)
    if not known or here is None:
        t = geometric_median(x_m, valid & truth[:, None])
        fused = fusion.Fused(t, np.full(len(t), np.nan), np.where(valid & truth[:, None], 1.0, 0.0), np.zeros(len(t)))
        return Weighing([a.id for a in subs], origin, x_m, valid, moved, np.full(len(subs), np.nan),
                        np.full(len(subs), np.nan), measured_ops[ops], [gold.get(a.operator_id or 0, (None, 0))[0] for a in subs],
                        [gold.get(a.operator_id or 0, (None, 0))[1] for a in subs], fused, None, "geometric_median")
    full = fusion.estimate(others + [here], prior_s, prior_n)
    # the reference scale: agreement on the task's other runs (the clicks' own scale) where there
    # is enough of it, else gold runs (a gold run scores the engine's smoothed track, so it
    # reads an operator somewhat better than their clicks)
    s_ref = np.where(np.isnan(prior_s), np.nan, prior_s)
    d_ref = np.where(np.isnan(prior_s), TYPICAL_DOF, 2.0 * prior_n)
    # how steady each operator is, measured elsewhere: a gold run's accuracy bounds its offsets
    tau_ref = np.where(np.isnan(prior_s), np.nan, prior_s)
    if others:
        agree = fusion.estimate(others, np.full(len(users), np.nan), np.zeros(len(users)))
        enough = agree.n_positions >= MIN_POSITIONS
        s_ref = np.where(enough, agree.sigma_m, s_ref)
        d_ref = np.where(enough, 2.0 * agree.n_positions, d_ref)
        if agree.tau_m is not None and agree.n_submissions is not None:
            tau_ref = np.where(agree.n_submissions > 0, np.fmin(agree.tau_m, tau_ref), tau_ref)
    ref = s_ref[ops]
    # never measured: expected to be as good as the median measured operator (the median of
    # this run's own estimates only when nobody is measured: two bad of three would set it)
    typical = float(np.nanmedian(s_ref)) if np.any(~np.isnan(s_ref)) else float(np.median(full.sigma_m[ops]))
    ref = np.where(np.isnan(ref), typical, ref)
    tau = full.tau_m[ops] if full.tau_m is not None else None
    # whose level the others' consensus stands on: operators measured steady elsewhere, not
    # this run's own fit (which makes whoever it put on the level look steady)
    test = fusion.chi2_test(here.x_m, here.valid, full.sigma_m[ops], ref, dof_ref=d_ref[ops], contributes=truth, tau_fit_m=tau,
                            tau_level_m=_merge_tau(tau_ref[ops], full.fused[-1], truth))
    pull = truth if chosen or not np.any(truth & (test.p >= ALPHA)) else truth & (test.p >= ALPHA)
    # the positions where the EM puts them; their uncertainty no smaller than what the
    # operators' steadiness measured elsewhere allows (the merge guard reads it)
    fused = fusion.fuse(x_m, valid & pull[:, None], full.sigma_m[ops], tau_m=tau)
    sure = fusion.fuse(x_m, valid & pull[:, None], full.sigma_m[ops], tau_m=_merge_tau(tau_ref[ops], full.fused[-1], pull),
                       t0_m=fused.t_m)
    fused.sigma_m, fused.p_m2 = np.fmax(fused.sigma_m, sure.sigma_m), np.fmax(fused.p_m2, sure.p_m2)
    return Weighing([a.id for a in subs], origin, x_m, valid, moved, full.sigma_m[ops], ref, measured_ops[ops],
                    [gold.get(a.operator_id or 0, (None, 0))[0] for a in subs],
                    [gold.get(a.operator_id or 0, (None, 0))[1] for a in subs], fused, test, "weighted")


def _merge_tau(tau_ref_m: np.ndarray, here: fusion.Fused, truth: np.ndarray) -> np.ndarray:
    """(m,) steady-offset scales for the fused result's uncertainty: each operator's as measured elsewhere.
    One never measured is as likely as any of the run's contributors to be the one off, so
    theirs is the scatter of the contributors' levels in this run (per axis, at least
    ``TAU0_M``): when the contributors disagree in level and nothing measured says who is
    right, the fused level is that unsure, and the merge guard sees it."""
    b = here.b_m if here.b_m is not None else np.zeros((len(truth), 2))
    c = b[truth] if truth.any() else b
    scatter = float(np.sqrt(np.mean(np.sum((c - c.mean(axis=0)) ** 2, axis=1)) / 2.0 * len(c) / max(len(c) - 1, 1)))
    return np.where(np.isnan(tau_ref_m), max(scatter, fusion.TAU0_M), tau_ref_m)
