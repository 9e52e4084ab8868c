"""pipeline/process/: process, the steps composed.

``wearable-gaze process``: its options checked, its frozen settings (``ProcessConfig``, the
presets), the session's files and the one cache of values, each step's entry ``run_<step>(conf,
inputs, progress)``, the steps' fingerprints and results, and the short sequence that calls them
(``process_session``, in ``session.py``).

docs/architecture.md, "The rooms of pipeline/"."""
