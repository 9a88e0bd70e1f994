"""Synthetic vineyard and urban worlds with ground truth (issue 3, in progress)."""
