"""Camera models (eq. 5-12), camera files and presets, the mount on the car, calibration."""
