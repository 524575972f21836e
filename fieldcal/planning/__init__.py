"""Planning a calibration procedure from the unit's noise and the accuracy wanted (issue 13)."""
