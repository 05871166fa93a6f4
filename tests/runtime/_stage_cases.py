"""Shared cases of the stage-structure tests: small staged NLPs (every staged transcription, path rows, a free final
time, graded grids, multiple shooting with several steps per shooting interval) and a random point inside bounds."""

from __future__ import annotations

import numpy as np

from myriad.runtime import load
from myriad.runtime.data import default_data
from myriad.runtime.integrators import Heun
from myriad.runtime.transcriptions import HermiteSimpson, MultipleShooting, Trapezoidal

VAN_DER_POL = "specs/van_der_pol.yaml"  # nonlinear dynamics, required final values
BRYSON_DENHAM = "tests/compiler/schema2/bryson_denham.yaml"  # a path row (a pure state constraint)
KEEP_OUT = "tests/compiler/schema2/keep_out_zone.yaml"  # nonlinear path rows and a free final time

# Node positions bunched towards both ends (what mesh refinement produces), 9 and 13 nodes.
GRADED_8 = tuple(float(s) for s in 0.5 - 0.5 * np.cos(np.linspace(0.0, np.pi, 9)))
GRADED_12 = tuple(float(s) for s in 0.5 - 0.5 * np.cos(np.linspace(0.0, np.pi, 13)))

CASES = {
    "trapezoidal-vdp": (VAN_DER_POL, Trapezoidal(intervals=8)),
    "trapezoidal-path": (BRYSON_DENHAM, Trapezoidal(intervals=8)),
    "trapezoidal-free-time-graded": (KEEP_OUT, Trapezoidal.on_grid(GRADED_8)),
    "hermite_simpson-vdp-graded": (VAN_DER_POL, HermiteSimpson.on_grid(GRADED_8)),
    "hermite_simpson-free-time": (KEEP_OUT, HermiteSimpson(intervals=6)),
    "multiple_shooting-vdp": (VAN_DER_POL, MultipleShooting(intervals=4, steps_per_interval=2)),
    "multiple_shooting-path-S3": (BRYSON_DENHAM, MultipleShooting(intervals=3, steps_per_interval=3)),
    # Heun's method: the structure is the integrator's whatever it is, and RK4's four stages cost compile time.
    "multiple_shooting-free-time-graded": (KEEP_OUT, MultipleShooting.on_grid(GRADED_12, steps_per_interval=3,
                                                                              integrator=Heun())),
}


def case(name: str):
    """(system, transcription, NLP, data) of a case (built afresh: transcribing is cheap, and a kept NLP would keep
    its compiled programs past the file's cache clearing)."""
    spec, transcription = CASES[name]
    system = load(spec)
    return system, transcription, transcription.transcribe(system), default_data(system)


def random_point(nlp, data, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A random ``z`` strictly inside the bounds near the initial guess (generic: no entry of a derivative vanishes by
    symmetry of the guess) and random multipliers ``y``."""
    rng = np.random.default_rng(seed)
    z0 = np.asarray(nlp.initial_guess(data), dtype=np.float64)
    z = z0 + 0.3 * nlp.z_scale * rng.standard_normal(z0.size)
    lo, hi = nlp.z_lower, nlp.z_upper
    pad = 1e-2 * np.where(np.isfinite(hi - lo), hi - lo, 1.0)
    z = np.clip(z, np.where(np.isfinite(lo), lo + pad, -np.inf), np.where(np.isfinite(hi), hi - pad, np.inf))
    return z, rng.standard_normal(nlp.n_constraints)
