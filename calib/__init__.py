"""calib: geometry and the four calibration stages (no Lightning here)."""
