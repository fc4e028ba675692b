"""Paper 002 (Powers & Pao): track-loss detection by KS tests on gated-measurement counts."""
