"""Cascaded position, velocity and current loops (field-oriented control), pure and compiled."""
