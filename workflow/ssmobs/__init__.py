"""ssmobs: observability of nonlinear Gaussian state space models (Hanebeck & Czado)."""

__version__ = "0.1.0"
