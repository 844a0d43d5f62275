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
==============  ===============================================================================
"""
