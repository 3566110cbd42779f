"""Samples -> runs and FRFs: the chirp runs of a test and their closed-loop frequency responses."""
