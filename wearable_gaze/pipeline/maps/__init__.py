"""pipeline/maps/: map building.

``wearable-gaze map`` and ``markers``: a marker map from a survey, a markerless map (pycolmap),
printable marker sheets.

docs/architecture.md, "The rooms of pipeline/"."""
