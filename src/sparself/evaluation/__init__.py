"""Evaluation: the held-out protocol, its typed results and the report."""
