"""metrics.json from a run's log: the simulator's truth, roles, estimation."""
