"""Paper 001: PDA against the all-neighbours weights linear in distance, one and two point targets."""
