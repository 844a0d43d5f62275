"""Bundled YAML presets of warpe-cl (shipped inside the wheel as ``warpe_cl.presets``)."""
