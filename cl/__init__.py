"""OpenCL C sources of warpe-cl (shipped inside the wheel as ``warpe_cl.cl``).

``walk.cl`` is the random walk; the ``*.h`` files are its pieces (precision, Philox, Fresnel,
scattering, tallies); ``selftest.cl`` exposes those pieces to the tests. The host joins them
in order with ``#line`` directives (:func:`warpe_cl.device.assemble_source`).
"""
