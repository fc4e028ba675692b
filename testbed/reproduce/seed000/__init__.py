"""Paper 000: a convoy of point targets on a known road, mixed measurements, gating, PDAF, the KS integral test."""
