"""Layer 4: fitting models to gonioreflectometer data. ``single`` (``fit``, ``FitResult``),
``batch`` (``fit_batch``: many problems at once), ``stream`` (``fit_stream``: any number of
problems in blocks, written to a resumable folder), ``problem`` (``FitProblem``, ``ParamLayout``:
which parameters a fit varies, their flat layout and transforms, the residual metrics; for a
registry name or any built model), ``guess`` (initial guesses); ``_lm`` (the batched solvers)
and ``_schedule`` (chunks, groups, blocks, sharding) serve ``batch``.

Named ``fitting`` (a noun) so that ``brdf_fit.fit`` is always the function."""
