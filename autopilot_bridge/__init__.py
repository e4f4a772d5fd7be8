"""The MAVLink autopilot: EKF, cascaded controllers, mixer, modes, missions, failsafes (pure), and the
MAVLink server and autopilot node (shells). It knows only its own parameters, never the simulator's truth."""
