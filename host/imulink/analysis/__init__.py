"""Analysis of filter outputs and sensor data: attitude errors, Allan deviation, calibration
fitting, offline navigation runs and their scenarios, evaluation scenarios, plots."""
