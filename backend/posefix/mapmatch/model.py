"""The map-matching model and its compact file format for devices.

A model is everything a tracker needs: the grid graph, the step-length model with its
heading bias, the feature weights and noise scales, and the beam. On disk it is one
uncompressed-member NumPy ``.npz`` (a zip of ``.npy`` arrays, readable with any zip and
npy reader; ``np.savez_compressed``), format version 1:

=================  =========  ===========================================================
member             dtype      meaning
=================  =========  ===========================================================
``format``         str        ``"posefix-mapmatch"``
``version``        int32      1
``grid``           float64    ``[cell_m, x0_m, y0_m, rows, cols]``
``ij``             int16/32   (V, 2) vertex (col, row); centre = x0 + (col + ½)·cell_m, ...
``indptr``         int32      (V+1,) CSR row pointers of the 8-neighbour edge graph
``indices``        int32      (E,) CSR column indices (neighbour vertex ids)
``offsets``        int8       (K, 2) step-transition offsets (dcol, drow); row 0 = (0, 0)
``trans_mask``     uint16/32  (V,) bit k set: u -> u + offsets[k] allowed (line of sight)
``georef``         float64    ``[lon0, lat0, dlon_per_m, dlat_per_m]`` or empty
``step_model``     float64    ``[height_m, alpha_s, beta, gamma_m, heading_bias_rad,
                              min_len_m, max_len_m]``
``weights``        float64    ``[w1, w2, w3, w4]`` for features f1..f4
``sigmas``         float64    ``[len_m, heading_rad, window_steps, min_span_m, wifi_corr_s]``
                              (files with the first four only read as wifi_corr_s = 20 s)
``beam``           float64    pruning width in nats (``inf`` = none)
``ellipse_scale``  float64    covariance scale of the reported ellipses (optional; absent = 1;
                              no longer learned: files from before keep theirs)
``walk_spread``    float64    ``[heading_sd_rad, scale_sd]``: σ of a walk's own heading offset
                              about ``heading_bias_rad`` and of its step-length scale (log)
                              about the model's, marginalised by ``track_walk`` (optional;
                              absent = [10°, 0.07])
=================  =========  ===========================================================

A device rebuilds the dense ``(V, K)`` transition tables from ``ij`` + ``trans_mask`` in
one pass (:attr:`GridGraph.succ`). Site1/F1 at 0.8 m is about 12 000 vertices.
"""

from __future__ import annotations

import io
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from posefix.mapmatch.features import FEATURE_NAMES, WIFI_CORR_S, FeatureSigmas
from posefix.mapmatch.floorplan import GeoRef
from posefix.mapmatch.graph import GridGraph
from posefix.mapmatch.sensors import StepModel
from posefix.mapmatch.viterbi import DEFAULT_BEAM

__all__ = ["Model", "ModelFormatError", "save_model", "load_model", "model_bytes", "FORMAT", "VERSION"]

FORMAT = "posefix-mapmatch"
VERSION = 1

DEFAULT_WEIGHTS = {"f1": 1.0, "f2": 0.0, "f3": 1.0, "f4": 0.5}

# How far one walk's heading offset and step-length scale stray from the floor's, before walks of
# the floor have measured it (learn.learn_walk_spread does). Heading: a phone's rotation-vector
# heading indoors is off by the magnetic field of the building's steel and by how the phone is
# held, 5-15° from one walk to the next. Scale: a step-frequency length model errs by 5-10 %
# for a walker it was not fitted to (stride differs with leg length and pace at one cadence).
WALK_HEADING_SD_RAD = float(np.deg2rad(10.0))
WALK_SCALE_SD = 0.07


class ModelFormatError(ValueError):
    """A model file that cannot be read; ``str()`` names file and member."""

    def __init__(self, file: str, field: str, message: str):
        self.file, self.field = file, field
        super().__init__(f"{file}:0: field {field}: {message}")


@dataclass
class Model:
    graph: GridGraph
    step_model: StepModel = field(default_factory=StepModel)
    weights: dict[str, float] = field(default_factory=lambda: dict(DEFAULT_WEIGHTS))
    sigmas: FeatureSigmas = field(default_factory=FeatureSigmas)
    beam: float | None = DEFAULT_BEAM
    ellipse_scale: float = 1.0  # reported covariance × this (files from before kept it; no longer learned)
    walk_heading_sd_rad: float = WALK_HEADING_SD_RAD  # learn.learn_walk_spread
    walk_scale_sd: float = WALK_SCALE_SD  # learn.learn_walk_spread (log of the step-length scale)

    def with_(self, **kw) -> "Model":
        return replace(self, **kw)


def _arrays(model: Model) -> dict[str, np.ndarray]:
    g = model.graph
    k = g.offsets.shape[0]
    sm, sg = model.step_model, model.sigmas
    return {
        "format": np.array(FORMAT),
        "version": np.array(VERSION, dtype=np.int32),
        "grid": np.array([g.cell_m, g.x0_m, g.y0_m, g.shape[0], g.shape[1]], dtype=np.float64),
        "ij": g.ij.astype(np.int16 if max(g.shape) < 32767 else np.int32),
        "indptr": g.indptr.astype(np.int32),
        "indices": g.indices.astype(np.int32),
        "offsets": g.offsets.astype(np.int8),
        "trans_mask": g.trans_mask.astype(np.uint16 if k <= 16 else np.uint32),
        "georef": g.georef.as_array() if g.georef is not None else np.zeros(0),
        "step_model": np.array([sm.height_m, sm.alpha_s, sm.beta, sm.gamma_m, sm.heading_bias_rad,
                                sm.min_len_m, sm.max_len_m]),
        "weights": np.array([model.weights[n] for n in FEATURE_NAMES]),
        "sigmas": np.array([sg.len_m, sg.heading_rad, sg.window_steps, sg.min_span_m, sg.wifi_corr_s]),
        "beam": np.array(np.inf if model.beam is None else model.beam),
        "ellipse_scale": np.array(float(model.ellipse_scale)),
        "walk_spread": np.array([float(model.walk_heading_sd_rad), float(model.walk_scale_sd)]),
    }


def model_bytes(model: Model) -> bytes:
    """The model file's bytes (its size is what a device downloads)."""
    buf = io.BytesIO()
    np.savez_compressed(buf, **_arrays(model))
    return buf.getvalue()


def save_model(model: Model, path: str | Path) -> int:
    """Write the model file; returns its size in bytes."""
    data = model_bytes(model)
    Path(path).write_bytes(data)
    return len(data)


def load_model(path: str | Path) -> Model:
    """Read a model file written by :func:`save_model` (checks format and version)."""
    p = str(path)
    try:
        z = np.load(p, allow_pickle=False)
    except (OSError, ValueError) as exc:
        raise ModelFormatError(p, "file", f"not a model file: {exc}") from exc
    with z:
        need = ["format", "version", "grid", "ij", "indptr", "indices", "offsets", "trans_mask",
                "georef", "step_model", "weights", "sigmas", "beam"]
        for name in need:
            if name not in z.files:
                raise ModelFormatError(p, name, "missing member")
        if str(z["format"]) != FORMAT:
            raise ModelFormatError(p, "format", f"expected {FORMAT!r}, got {str(z['format'])!r}")
        if int(z["version"]) != VERSION:
            raise ModelFormatError(p, "version", f"unsupported version {int(z['version'])}")
        cell, x0, y0, rows, cols = z["grid"].tolist()
        geo = z["georef"]
        graph = GridGraph(cell_m=cell, x0_m=x0, y0_m=y0, shape=(int(rows), int(cols)),
                          ij=z["ij"].astype(np.int32), indptr=z["indptr"], indices=z["indices"],
                          offsets=z["offsets"].astype(np.int64), trans_mask=z["trans_mask"].astype(np.uint32),
                          georef=GeoRef(*geo.tolist()) if geo.size == 4 else None)
        h, a, b, gm, hb, lo, hi = z["step_model"].tolist()
        w = z["weights"].tolist()
        s = z["sigmas"].tolist()
        if len(s) not in (4, 5):
            raise ModelFormatError(p, "sigmas", f"expected 4 or 5 numbers, got {len(s)}")
        # Files from before wifi_corr_s read with the default: counting every scan as
        # independent was not a choice recorded in them, only the code's behaviour then.
        tau = s[4] if len(s) == 5 else WIFI_CORR_S
        if not (np.isfinite(tau) and tau >= 0.0):
            raise ModelFormatError(p, "sigmas", f"wifi_corr_s (5th entry) must be a number of seconds >= 0, got {tau}")
        beam = float(z["beam"])
        ell = float(z["ellipse_scale"]) if "ellipse_scale" in z.files else 1.0
        if not (np.isfinite(ell) and ell > 0.0):
            raise ModelFormatError(p, "ellipse_scale", f"must be a positive number, got {ell}")
        spread = z["walk_spread"].tolist() if "walk_spread" in z.files else [WALK_HEADING_SD_RAD, WALK_SCALE_SD]
        if not (len(spread) == 2 and all(np.isfinite(spread)) and 0.0 <= spread[0] <= np.pi / 4
                and 0.0 <= spread[1] <= 0.5):
            raise ModelFormatError(p, "walk_spread", "expected [heading_sd_rad in [0, pi/4], scale_sd in [0, 0.5]], "
                                   f"got {spread}")
    return Model(graph=graph,
                 step_model=StepModel(height_m=h, alpha_s=a, beta=b, gamma_m=gm, heading_bias_rad=hb,
                                      min_len_m=lo, max_len_m=hi),
                 weights=dict(zip(FEATURE_NAMES, w)),
                 sigmas=FeatureSigmas(len_m=s[0], heading_rad=s[1], window_steps=int(s[2]), min_span_m=s[3],
                                      wifi_corr_s=float(tau)),
                 beam=None if not np.isfinite(beam) else beam, ellipse_scale=ell,
                 walk_heading_sd_rad=float(spread[0]), walk_scale_sd=float(spread[1]))
