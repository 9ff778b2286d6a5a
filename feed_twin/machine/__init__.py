"""The machine twin: every simulated axis of one machine under one NC (config, simulation,
contour error)."""
