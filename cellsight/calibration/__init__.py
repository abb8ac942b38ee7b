"""Cell calibration: a ChArUco board on a robot flange, the cell's cameras and robot bases."""
