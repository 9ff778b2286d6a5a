"""Comparison of twin and measurement: alignment, residuals, effect naming, identification."""
