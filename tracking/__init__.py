"""Head pose from the scene camera: markers, PnP, homography, pose over time (issue 5)."""
