"""The correction engine's numerics: keyframes, the five terms, the solver, drift, propagation, rules (numpy/scipy only)."""
