"""Controllers and reference trajectories shared by offline simulation and the real-time loop."""
