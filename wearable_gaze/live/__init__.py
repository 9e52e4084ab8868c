"""The live wearable session: serial eye data, camera, real-time estimates, publishing, recording."""
