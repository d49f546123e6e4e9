"""Fault detection and isolation (no ROS): P-II/P-III UKF and P-IV-style parity residual generators behind
one interface, thresholds, isolation, and the offline analysis of a bag."""
