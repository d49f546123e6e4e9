"""Fault detection and isolation: P-II/P-III UKF and P-IV-style parity residuals, thresholds, isolation."""
