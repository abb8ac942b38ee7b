"""The cell's two clocks (paper, Section V): vision and trajectory planning at the cameras'
frame rate, motion control (interpolating filter, CLIK, the simulator's step) at the
controller's rate. Hz."""

VISION_HZ = 26.0
CONTROL_HZ = 500.0
