"""User-study sessions: conditions, motion-capture ground truth, synchronised logs and per-participant
metrics."""
