"""The estimators' kernels: Numba loops that trust validated input.

Nothing here validates or imports the registry; :mod:`surfnorm.methods` names,
for every method, the module and function here that computes it (``kernel=`` of
its entry), and ``surfnorm methods`` and the documentation's page "Methods and
their kernels" list them, generated from the registry. One module per family of
estimators; the modules that several kernels share::

    _rows           helpers shared by the kernels (private): clamped reads, runs of
                    fully valid pixels, exp, normalise-and-store, orientation, points
    gradients       FD and DAG depth gradients (D2NT eq. 10-14)
    mnr             MNR (D2NT Sec. III-C, IV-A), on any normal map
    sensor_noise    the frame's noise profile (adaptive_fit's windows, auto's decision, sigma)
    uncertainty     each normal's sigma (estimate(..., uncertainty=True))

``adaptive_fit`` is the plane fit itself (the fits, the noise and edge tests, the band
kernel) and three private modules of its own: ``_windows`` (radii from the noise, the
windows' moment sums from integral rows), ``_assembly`` (fitted planes to every
pixel's normal) and ``_schedule`` (the stride, the row bands on threads, what is kept
between frames: no numerics).

A new estimator's kernel is a module of its own here (or a function in the module
of its family): see the documentation's page "Add an estimator".
"""
