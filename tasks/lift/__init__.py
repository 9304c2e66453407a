"""Stage 3, lift: 2D keypoints to 3D in one world frame, then physics cleanup in MuJoCo."""
