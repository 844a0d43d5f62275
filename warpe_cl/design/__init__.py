"""The instrument-design study of ``warpe-cl design`` (docs/design.md): for every surface of
one or more families (sweep databases) and every candidate instrument, the expected posterior
width of each swept key and derived quantity from the Fisher information of the calibrated
likelihood, and whether each surface is told apart from its neighbours.

Modules: :mod:`.study` (the study file), :mod:`.family` (a database and its points),
:mod:`.fisher` (the information), :mod:`.expected` (widths per node), :mod:`.result` (the
Dataset and the summary table), :mod:`.figures`.
"""
