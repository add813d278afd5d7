"""Evaluators: truth + tracker outputs → polars metrics tables, plots and baseline checks."""
