"""The 15-body boxer humanoid: its MJCF (`boxer`) and kinematics (`kinematics`)."""
