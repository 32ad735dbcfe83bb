"""plush_opt: optimisation-centric control of tendon-driven plush robots."""

__version__ = "0.1.0"
