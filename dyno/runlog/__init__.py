"""Run logs: one directory per run, valid at every instant (see docs/runlog.md)."""
