"""The search: eq. (17)'s objective, the parameter scaling, its sensitivities and the global then
local search."""
