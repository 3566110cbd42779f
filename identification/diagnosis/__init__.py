"""Missing-physics diagnosis: where the identified model misses the recordings (mismatch)."""
