"""The closed-loop simulated study (``seesys study simulate``): simulated operators through the real pipeline."""
