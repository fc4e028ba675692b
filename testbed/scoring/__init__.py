"""Scoring: the thesis's TP / FP / break-up rates and the standard MOT metrics of truth and tracks tables."""
