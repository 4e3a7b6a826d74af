"""Entry point of the Python simulated device; the logic lives in ``rehab_hil.devices.sim_device``."""
