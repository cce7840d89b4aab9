"""Per-condition statistics, tables and plots for user studies and estimator evaluations."""
