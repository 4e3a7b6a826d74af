"""The simulated patient: small plant parts (a passive finger, voluntary torque toward the task's
target with a capacity per direction, slacking, three-compartment fatigue, a velocity-dependent
stretch reflex) that a simulated rig attaches to its plant from a ``PATIENT.toml`` (``profiles/sim/``).
The host's model never sees them: only the simulated device does (``--sim-patient``)."""
