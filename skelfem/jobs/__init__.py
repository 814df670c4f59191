"""Whole jobs on a communicator: one simulation to files, sweeps of many, the Newton cost bench."""
