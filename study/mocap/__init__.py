"""Motion-capture ground truth: live logging (motioncapture), importers (Vicon CSV, TUM), clock-offset and
hand-eye calibration, and the calibrated ground truth of a study session."""
