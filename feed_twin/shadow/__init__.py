"""Shadow twin beside a real axis: streams on a slot grid, residuals, health, bag replay."""
