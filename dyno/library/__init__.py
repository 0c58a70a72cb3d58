"""The run library: an index of every run (SQLite, in the runs directory), comparisons, exports."""
