"""Constrained linear and nonlinear model predictive control."""
