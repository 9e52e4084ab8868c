"""pipeline/report/: the report and its views.

report.html and what it shows: the targets' table beside the truth (and the matching of estimates to
a simulated session's truth), the plots, the 3D view (``view3d.js``), the overlay video, the
credible regions as lines, and viewing in rerun.

docs/architecture.md, "The rooms of pipeline/"."""
