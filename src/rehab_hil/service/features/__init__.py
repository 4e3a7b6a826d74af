"""The session's features (``base.Feature``): recording, zenoh telemetry, Foxglove, the live twin and the
patient's torque, the learning on the rig and its thermal re-plan, a kept assistance, and a simulated
patient's truth. Each is opened by the session only when asked for, and adds its part of the result."""
