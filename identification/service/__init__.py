"""The worker service: the daemon's event stream in, FRFs and identifications out."""
