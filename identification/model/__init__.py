"""The model side: a recorded test simulated as the vehicle ran it, and its |G_DRV|."""
