"""Scenario specs: the typed, frozen, strictly checked description of a run (no simulator is imported here)."""
