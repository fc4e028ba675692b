"""Pipeline: the run loop (sense, track, score, record), its tables and output folders, reading a run folder back."""
