"""Camera intrinsics, undistortion and eye calibration (issue 4)."""
