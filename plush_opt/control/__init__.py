"""Inverse control: contractions that bring the equilibrium to targets."""
