"""Offline replay of tracking algorithms: stage processors, numerical cores and the CLI."""

__version__ = "0.1.0"
