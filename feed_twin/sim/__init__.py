"""The engine: the assembled plant and the controller in one compiled fixed-step loop."""
