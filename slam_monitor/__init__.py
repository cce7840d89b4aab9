"""On the device: camera sources, ORB-SLAM3 tracking, the runtime-status monitor, PSD matrices, the feature
stream and the session logs."""
