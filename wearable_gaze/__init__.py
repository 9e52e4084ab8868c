"""wearable-gaze: where in 3D a person looks, from a head-worn binocular eye tracker.

The application layer: command line, session files, devices, simulation and reports, on top of
the ``estimator``, ``calibration`` and ``tracking`` libraries.
"""

__version__ = "0.1.0"
