"""The simulator: vehicle physics, wind, sensors, battery and camera (docs/simulator.md)."""
