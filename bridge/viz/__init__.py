"""Rerun viewer output: the fleet in 3-D, its time series, status and events."""
