"""Inversion: from recorded shots back to the surface parameters of a sweep database, with
honest uncertainties (docs/inversion.md).

==============  ===============================================================================
module          what
==============  ===============================================================================
``observed``    recorded shots: a ``warpe-cl instrument`` file or CSV files (docs/interface.md §5.7)
``space``       the database's axes and the surface response anywhere inside its grid (§2)
``forward``     surface response -> expected samples and their variance, pulse-width nuisance (§3)
``likelihood``  the shots' likelihood, per-shot amplitude and arrival marginalised (§4.1)
``counting``    the likelihood of photon-counting histograms (ATLAS, §4.2)
``posterior``   grid posterior, refined where the mass is; intervals and marginals (§5)
``result``      the FIT Dataset (§6)
``plot``        the figure: shots, best fit, 68 % band, pairwise posterior
``invert``      :func:`invert`, which ties them together
``checks``      log evidence, complete goodness of fit and warnings of one inversion (§5.1-§5.3)
``comparison``  :func:`compare`: the same shots against several databases, ranked by ln Z (§5.4)
==============  ===============================================================================

``warpe_cl.inversion.compare`` is :func:`warpe_cl.inversion.comparison.compare`, imported on
first use (this package's modules load no scipy until then).
"""


def __getattr__(name: str):
    """``compare`` on first use (:func:`warpe_cl.inversion.comparison.compare`)."""
    if name == "compare":
        import importlib
        return importlib.import_module(".comparison", __name__).compare
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
