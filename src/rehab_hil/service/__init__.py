"""The host service around the real-time loop: a session built one way (``session.open_session``), the
loop itself (``runner``), what it computes each cycle (estimation, controllers, the supervisor), the
sinks it hands its records to after the write (``sinks``, ``records``, ``recorder``), and the run
directory a recorded session leaves (``run_dir``)."""
