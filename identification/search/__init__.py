"""The search: eq. (17)'s objective, the parameter scaling and the global then local search."""
