"""OpenCL C sources of warpe-cl (shipped inside the wheel as ``warpe_cl.cl``).

``walk.cl`` is the random walk; the ``*.h`` files are its pieces (precision, Philox, Fresnel,
scattering, tallies) and the parts of each build's precision, lane width and driver
(``*_single.h``, ``*_double.h``, ``lanes_*.h``); ``selftest.cl`` exposes those pieces to the
tests. The host picks a build's files (:func:`warpe_cl.device.program_files`) and joins them
in order with ``#line`` directives (:func:`warpe_cl.device.assemble_source`).
"""
