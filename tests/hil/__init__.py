"""Hardware-in-the-loop harness: processes on one python-can bus (see README.md here)."""
