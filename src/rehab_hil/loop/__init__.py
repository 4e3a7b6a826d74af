"""The real-time loop and its low-level types, below the session and the live views: the loop itself
(``runner``), what it computes each cycle (``estimation``, ``controllers``, ``supervisor``), the records
it hands on after the write (``records``) through the sinks (``sinks``) or the shared-memory ring of a
loop process (``ring``, ``process``), the recorder and the run directory (``recorder``, ``run_dir``).
Nothing here imports the session (``service``), the telemetry or the twin."""
