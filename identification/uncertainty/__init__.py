"""Uncertainty of the identified parameters: sensitivities and likelihood profiles."""
