"""Learning on simulated walks: CRF weights by conditional likelihood, γ by hard EM, heading bias."""

from dataclasses import replace

import numpy as np

from posefix.mapmatch.features import FeatureSigmas
from posefix.mapmatch.floorplan import raster_from_polygons
from posefix.mapmatch.graph import build_graph
from posefix.mapmatch.learn import WalkFeatures, learn_step_constants, learn_weights
from posefix.mapmatch.model import Model
from posefix.mapmatch.sensors import StepModel, Steps


def room(w, h, cell, reach):
    poly = [[np.array([[0, 0], [w, 0], [w, h], [0, h]], float)]]
    return build_graph(raster_from_polygons(w, h, poly, res_m=0.05), cell_m=cell, reach_m=reach, min_component_m2=0.1)


def sample_path(g, prior, trans, rng):
    """Exact sample from the chain CRF: forward filtering, backward sampling (dense, tiny V)."""
    t_n = trans.shape[0]
    alpha = [prior - np.logaddexp.reduce(prior)]
    for t in range(t_n):
        m = np.concatenate([alpha[-1], [-np.inf]])[g.pred] + trans[t][None, :]
        alpha.append(np.logaddexp.reduce(m, axis=1))
    p = np.exp(alpha[-1] - np.logaddexp.reduce(alpha[-1]))
    y = [rng.choice(g.n_vertices, p=p)]
    for t in range(t_n - 1, -1, -1):
        v = y[-1]
        u = g.pred[v]
        lw = np.where(u >= 0, np.concatenate([alpha[t], [-np.inf]])[u] + trans[t], -np.inf)
        w = np.exp(lw - np.logaddexp.reduce(lw))
        y.append(int(u[rng.choice(len(u), p=w)]))
    return np.array(y[::-1])


def test_learning_recovers_known_weights():
    g = room(5.0, 5.0, 1.0, 1.5)
    rng = np.random.default_rng(1)
    true_w = {"f1": 1.5, "f2": 0.4, "f3": 0.0, "f4": 0.0}
    t_n, k_n = 12, g.offsets.shape[0]
    data = []
    for _ in range(80):
        f1 = rng.normal(size=(t_n, k_n))
        f2 = rng.normal(size=(t_n, k_n))
        prior = np.zeros(g.n_vertices)
        y = sample_path(g, prior, true_w["f1"] * f1 + true_w["f2"] * f2, rng)
        wf = WalkFeatures(F={"f1": f1, "f2": f2, "f3": [None] * t_n, "f4": [None] * t_n}, log_prior=prior,
                          t_ms=np.arange(t_n + 1))
        clamp = []
        for t in range(t_n):  # fully observed: every y_t known
            c = np.full(g.n_vertices, -np.inf)
            c[y[t + 1]] = 0.0
            clamp.append(c)
        data.append((wf, clamp))
    start = Model(graph=g, weights={"f1": 0.5, "f2": 1.5, "f3": 0.0, "f4": 0.0})
    fit = learn_weights(start, data, learn=("f1", "f2"), sigma_w=100.0, beam=None)
    assert abs(fit.weights["f1"] - 1.5) < 0.25, fit
    assert abs(fit.weights["f2"] - 0.4) < 0.2, fit


LEG_STEPS, RISE_STEPS = 18, 5


def serpentine(step_m: float):
    """Four corridors (0.8 m wide) joined at alternate ends, sized for legs of LEG_STEPS
    and rises of RISE_STEPS steps of ``step_m``: a walker must turn at the walls.

    The recovered γ can only be as good as the corridor width allows (a path may turn up
    to a width early), so the corridors are narrow and the legs long.
    """
    leg, rise = LEG_STEPS * step_m, RISE_STEPS * step_m
    x_a, x_b = 1.0, 1.0 + leg
    polys = []
    for i in range(4):
        yc = 1.0 + i * rise
        polys.append([np.array([[x_a - 0.4, yc - 0.4], [x_b + 0.4, yc - 0.4], [x_b + 0.4, yc + 0.4], [x_a - 0.4, yc + 0.4]])])
        if i < 3:
            xc = x_b if i % 2 == 0 else x_a
            polys.append([np.array([[xc - 0.4, yc], [xc + 0.4, yc], [xc + 0.4, yc + rise], [xc - 0.4, yc + rise]])])
    r = raster_from_polygons(x_b + 1.0, 2.0 + 3 * rise, polys, res_m=0.05)
    return build_graph(r, cell_m=0.4, reach_m=0.9, min_component_m2=1.0)


def simulate_serpentine_steps(rng) -> tuple[Steps, tuple]:
    """East, north, west, north, ... along the centre line at a steady 1.8 Hz."""
    legs = [0.0, np.pi / 2, np.pi, np.pi / 2, 0.0, np.pi / 2, np.pi]
    heads = []
    for i, th in enumerate(legs):
        n = LEG_STEPS if i % 2 == 0 else RISE_STEPS
        heads += list(th + rng.normal(0.0, np.deg2rad(4.0), size=n))
    n = len(heads)
    return Steps(t_ms=np.arange(1, n + 1) * 555, freq_hz=np.full(n, 1.8), heading_rad=np.array(heads)), (1.0, 1.0)


def test_step_length_hard_em_recovers_gamma():
    true_sm = StepModel(gamma_m=-0.12)
    g = serpentine(float(true_sm.length_m(np.array([1.8]))[0]))
    rng = np.random.default_rng(4)
    walks = [simulate_serpentine_steps(rng) for _ in range(3)]
    model = Model(graph=g, step_model=StepModel(gamma_m=0.08), sigmas=FeatureSigmas(len_m=0.3))
    sm = learn_step_constants(model, walks, iters=8)
    assert abs(sm.gamma_m - (-0.12)) < 0.02, sm.gamma_m
    assert sm.alpha_s == true_sm.alpha_s and sm.beta == true_sm.beta  # only γ was free
    # Starting from below converges too (the basin is about ±0.2 m around the truth:
    # much shorter steps put every turn far from its corner and the path loses the walls).
    sm2 = learn_step_constants(model.with_(step_model=replace(model.step_model, gamma_m=-0.2)), walks, iters=8)
    assert abs(sm2.gamma_m - (-0.12)) < 0.02, sm2.gamma_m


def test_step_scale_is_the_ratio_of_surveyed_to_dead_reckoned_distance():
    from pathlib import Path

    from posefix.mapmatch.learn import learn_step_scale, waypoint_segments
    from posefix.mapmatch.sensors import read_walk, steps_from_walk

    floor = Path(__file__).resolve().parents[2] / "data" / "indoor-site1-F1"
    walk = read_walk(floor / "walks" / "5dd9e7aac5b77e0006b1732b.txt")
    sm0 = StepModel()
    sm1 = learn_step_scale([walk], sm0)
    dd, dw = waypoint_segments([walk], sm0)
    s = np.linalg.norm(dw, axis=1).sum() / np.linalg.norm(dd, axis=1).sum()
    steps = steps_from_walk(walk)
    # Every step is lengthened by s and keeps its heading.
    v0, v1 = steps.vectors_m(sm0), steps.vectors_m(sm1)
    assert np.allclose(v1, s * v0)
    # After scaling, the dead-reckoned distance over the segments equals the surveyed one.
    dd1, dw1 = waypoint_segments([walk], sm1)
    assert np.isclose(np.linalg.norm(dd1, axis=1).sum(), np.linalg.norm(dw1, axis=1).sum())
    # Stretching the survey by 20 % about the start stretches the learned scale by 20 %.
    w2 = replace(walk, waypoints=np.column_stack([walk.waypoints[:, 0], walk.waypoints[0, 1:3]
                                                  + 1.2 * (walk.waypoints[:, 1:3] - walk.waypoints[0, 1:3])]))
    assert np.isclose(learn_step_scale([w2], sm0).height_m, 1.2 * sm1.height_m)
    # Waypoints in the wrong unit (decimetres) are refused with a clear message.
    w10 = replace(walk, waypoints=np.column_stack([walk.waypoints[:, 0], 10.0 * walk.waypoints[:, 1:3]]))
    try:
        learn_step_scale([w10], sm0)
    except ValueError as exc:
        assert "step-length scale" in str(exc) and "units" in str(exc)
    else:
        raise AssertionError("a tenfold scale must be refused")
