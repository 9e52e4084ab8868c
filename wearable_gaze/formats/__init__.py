"""The file formats: one module per format, each with one reader and one writer (docs/formats.md).

session (manifest, Session), eye_samples (eye CSV), poses (pose CSV), video (scene video, frame
timestamps), camera (camera JSON, OpenCV YAML/XML), eyes (eyes.json), markermap (marker map JSON),
viewlines (view-line CSV), serial_protocol (the recorder's serial lines); the mechanisms they
share: jsonio (+ schemas/: reading, checking and writing JSON), tables (CSV), atomic (writes).
"""
