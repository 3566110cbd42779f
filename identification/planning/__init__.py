"""Test design (``dtid plan``): predict each parameter's precision for a chirp test and find the
shortest test that meets the engineer's targets (docs/planning.md)."""
