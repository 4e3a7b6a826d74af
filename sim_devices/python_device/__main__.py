"""``python -m sim_devices.python_device --config configs/finger_extensor.toml [--clock lockstep]``."""

import sys

from rehab_hil.devices.sim_device import main

sys.exit(main())
