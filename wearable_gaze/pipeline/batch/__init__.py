"""pipeline/batch/: batch running.

``wearable-gaze batch``: the sessions found and planned, the workers that run them (local processes
or a Dask cluster), and the batch's report.

docs/architecture.md, "The rooms of pipeline/"."""
