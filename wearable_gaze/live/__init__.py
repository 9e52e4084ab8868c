"""The live wearable session: serial eye data, camera, real-time estimates, publishing, recording.

Parts (docs/live.md, The parts): ``serial_in`` and ``camera_in`` (input readers), ``clock``,
``head`` (head tracking), ``estimation``, ``messages``, ``publish``, ``record``, ``stats``;
``loop`` composes them, ``app`` builds and wires them (``open_session``, ``run_live``)."""
