"""Truth-free track-loss tests: is a track still on a real target?

Modules: ``ks`` (exact and asymptotic two-sided Kolmogorov-Smirnov critical values), ``regime`` (paper 002's
track regime detector on gated-measurement counts), ``ks_integral`` (paper 000's windowed KS integral test on
innovations). Import the module you need; this package imports nothing heavy.

Every ``trackers.Track`` carries the regime detector's verdict (``Track.regime``: unknown, tracking, track-lost,
ambiguous; ``Track.regime_state``) and the tracker logs the ``ks_regime``, ``ks_D_T``, ``ks_D_L``, ``ks_d_n`` and
``ks_n`` diagnostics; ``ManagementParams.deletion = "ks"`` (or ``"manager+ks"``) deletes on track-lost.
See docs/trackloss.md.
"""
