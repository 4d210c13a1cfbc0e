"""Evaluation against ground truth: the metric and its PR-curve picture."""
