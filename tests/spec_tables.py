"""The Robonaut paper's tables as specs/robonaut-a.md gives them, typed in (not read from the profile)."""

RN_ARM = ["shoulder_roll", "shoulder_pitch", "elbow_roll", "elbow_pitch", "wrist_roll", "wrist_pitch", "wrist_yaw"]
RN_NECK = ["neck_yaw", "neck_pitch", "neck_roll"]
RN_JOINTS = RN_ARM + RN_NECK
# The paper's Table I (deg, cm), columns in RN_JOINTS order.
RN_TABLE_I = {
    "theta": [0, 0, 0, 0, 0, -90, 0, 0, -60, -90],
    "d": [30.48, 0, 36.83, 0, 36.83, 0, -1.27, 28.575, 0, 2.92],
    "alpha": [-90, 90, -90, 90, -90, 90, 0, 90, 90, 0],
    "a": [-6.35, 6.35, -5.08, 5.08, 0, 0, 3.81, -5.08, -11.96, 0],
}
# The paper's Table II (the simulator's true robot); alpha unchanged.
RN_TABLE_II = {
    "theta": [-8.444, -1.535, -2.013, -3.780, 3.414, -95.58, 4.227, -1.057, -59.969, -90.0],
    "d": [31.856, 0, 35.498, 0, 35.498, 0, -0.053, 28.292, 0, 2.537],
    "alpha": RN_TABLE_I["alpha"],
    "a": [-5.056, 5.056, -0.99, 0.99, 0, 0, 11.358, -6.773, -12.667, 0],
}
