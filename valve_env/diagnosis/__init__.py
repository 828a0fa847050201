"""Diagnosis: find what the calibrated valve simulation gets wrong, name the physical cause,
extend the model and measure the gain (issue 6; SPEC sections 3 and 4)."""
