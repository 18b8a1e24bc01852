"""A run's record: the trajectory (segments, events, stats; NPZ, CSV, JSON) and its summary."""
