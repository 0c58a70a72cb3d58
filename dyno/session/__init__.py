"""The run session: one composition root, the run's safety wiring, drills, its summary."""
