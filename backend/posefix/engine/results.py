"""What the engine hands back: a keyframe solution, a full-rate correction, a live-drag preview."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from posefix.core import terms as T
from posefix.core.drift import DriftEstimate
from posefix.core.keyframes import KeyframeSet
from posefix.core.rules import Refusal
from posefix.core.run import PoseRun
from posefix.core.solver import Linearisation, SolverResult
from posefix.engine.edits import Edits


class EditRefusedError(ValueError):
    """Edits refused by the edit rules; ``refusals`` lists each with its reason."""

    def __init__(self, refusals: list[Refusal]):
        self.refusals = refusals
        super().__init__("; ".join(f"keyframe {r.index}: {r.reason}: {r.message}" for r in refusals))


@dataclass(frozen=True)
class Solution:
    """A keyframe-level solution: keyframes, solver result, drift, and the raw state."""

    keyframes: KeyframeSet
    solver: SolverResult
    drift: DriftEstimate
    x: np.ndarray  # (6k_active,) state over the active (non-removed) keyframes
    active: np.ndarray  # (k,) bool: keyframe took part in the optimisation
    flags: list[Refusal] = field(default_factory=list)
    terms: T.Terms | None = None  # the problem that was solved (for diagnostics, benchmarks)
    # the relative and gravity terms' model at the last full solve's answer (see solver.Linearisation):
    # a local solve warm-started from this solution re-uses it instead of linearising its window
    linearisation: Linearisation | None = field(default=None, repr=False, compare=False)


@dataclass(frozen=True)
class Correction:
    """The result of ``correct``: the corrected full-rate run and how it was obtained."""

    run: PoseRun
    keyframes: KeyframeSet
    solver: SolverResult
    drift: DriftEstimate
    kept_rows: np.ndarray  # rows of the input present in ``run`` (deleted keyframes removed)
    flags: list[Refusal] = field(default_factory=list)
    propagation_time_s: float = 0.0
    x: np.ndarray | None = None  # the keyframe state solved for (for warm starts)
    active: np.ndarray | None = None
    terms: T.Terms | None = None
    linearisation: Linearisation | None = field(default=None, repr=False, compare=False)

    @property
    def solution(self) -> Solution:
        """The keyframe-level solution behind this correction (a warm start for the next solve)."""
        return Solution(self.keyframes, self.solver, self.drift, self.x, self.active, self.flags, self.terms,
                        self.linearisation)


@dataclass(frozen=True)
class Preview:
    """A live-drag answer: corrected keyframe positions, what was refused or flagged, the edit
    set it solved (the base revision's edits with the batch merged in), and what was solved
    (``info``: mode local|full, the window re-solved, how the drift model was applied)."""

    lon_deg: np.ndarray  # (k,)
    lat_deg: np.ndarray  # (k,)
    solution: Solution
    refusals: list[Refusal]
    flags: list[Refusal] = field(default_factory=list)
    edits: Edits | None = None
    info: dict = field(default_factory=dict)
