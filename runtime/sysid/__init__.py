"""System identification: datasets from a system's true dynamics, parametric and Neural ODE models, fitting, and
planning on what was learned. See README.md in this folder."""
