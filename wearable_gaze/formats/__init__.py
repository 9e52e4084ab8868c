"""The file formats: one module per format, each with one reader and one writer (docs/formats.md).

session (manifest, Session), eye_samples (eye CSV), poses (pose CSV), video (scene video, frame
timestamps), camera (camera JSON, OpenCV YAML/XML), eyes (eyes.json), markermap (marker map JSON),
viewlines (view-line CSV), serial_protocol (the recorder's serial lines), board and walls (the
calibration recordings), images (still images), targets (targets.json, targets.csv), truth (the
simulator's truth files of their own); the mechanisms they
share: jsonio (+ schemas/: reading, checking and writing JSON), tables (CSV), atomic (writes).
"""
