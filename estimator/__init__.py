"""3D gaze estimators from view lines: geometry, triangulation, likelihood and voxel methods."""
