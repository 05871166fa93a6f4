"""Registries that drive the parametrised tests (a meta-test checks they are complete)."""

import math
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
SPECS_DIR = ROOT / "specs"
ALL_SPECS = sorted(SPECS_DIR.glob("*.yaml"))
ALL_SPEC_NAMES = [p.stem for p in ALL_SPECS]


def sample_interval(lo, hi, centre, rng, n):
    """n points strictly inside [lo, hi]; an infinite side gets a window scaled by the centre (x0; 0 for controls)."""
    width = max(1.0, abs(centre))
    lo = centre - 2 * width if math.isinf(lo) else lo
    hi = centre + 2 * width if math.isinf(hi) else hi
    pad = 1e-3 * (hi - lo)
    return rng.uniform(lo + pad, hi - pad, size=n) if hi > lo else np.full(n, lo)


class CompileCounter:
    """Counts XLA backend compilations while active (JAX's monitoring events), for tests that a program compiles once
    and is reused."""

    def __init__(self):
        self.events: list[str] = []

    def _listener(self, event, duration, **kwargs):
        if "backend_compile" in event:
            self.events.append(event)

    def __enter__(self):
        import jax

        jax.monitoring.register_event_duration_secs_listener(self._listener)
        return self

    def __exit__(self, *exc):
        import jax

        jax.monitoring.unregister_event_duration_listener(self._listener)
