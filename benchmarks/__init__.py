"""Benchmarks of drivetrain-id (not tests: they measure and report, they assert nothing)."""
