"""Robustness: option sweeps over every demo, damaged input and restart files, interrupted runs."""
