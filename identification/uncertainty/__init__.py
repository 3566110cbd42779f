"""Uncertainty of the identified parameters: likelihood profiles and their verdicts."""
