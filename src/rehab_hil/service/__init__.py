"""The session around the real-time loop (``rehab_hil.loop``), built one way (``session.open_session``):
the rig opened, homed and checked, the loop started in a process of its own (or in this one, in
lockstep), and the session's features (recording, telemetry, Foxglove, the live twin, the learning on
the rig, kept assistance, a simulated patient's truth) opened beside it and closed after it."""
