"""Studies of many runs: plans (grids, random, Latin hypercube), one run's quantities, the
results table, the local pool and Dask backends, the figures; ``pcmm sweep``."""
