"""`feed-twin simulate`: run a model against a measured run's command (see analysis.cli)."""

from feed_twin.analysis.cli import configure_simulate as configure
from feed_twin.analysis.cli import main_simulate as main

__all__ = ["configure", "main"]
