"""Unit conversions every part shares."""

#: Millimetres per metre: the label and estimates are kept in metres; reports, some RTS channels and depth images
#: (16-bit PNG, rosbag ``16UC1``) are in millimetres.
MM_PER_M = 1000.0
