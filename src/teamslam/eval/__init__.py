"""Evaluation: Monte Carlo driver, consistency statistics and figures."""
