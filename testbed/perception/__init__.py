"""Perception characterisation: measured P_D, centre error, merges, splits and clutter of the perception stack."""
