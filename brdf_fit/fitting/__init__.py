"""Layer 4: fitting models to gonioreflectometer data. ``single`` (``fit``, ``FitResult``),
``batch`` (``fit_batch``: many problems at once), ``guess`` (initial guesses).

Named ``fitting`` (a noun) so that ``brdf_fit.fit`` is always the function."""
