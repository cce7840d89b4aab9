"""Synthetic training data: procedurally generated rooms rendered along real and generated handheld
trajectories, with camera effects computed from the true motion (docs/synthetic-data.md)."""
