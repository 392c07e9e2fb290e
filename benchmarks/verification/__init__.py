"""Verification: manufactured and closed-form solutions, the observed order of convergence."""
