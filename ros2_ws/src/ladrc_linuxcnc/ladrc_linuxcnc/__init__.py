"""LinuxCNC as the height controller's CNC: the bridge, the machine configuration, the run.

Nothing is imported here: :mod:`.hal_component`, :mod:`.display` and :mod:`.z_filter` run on the
system's Python inside LinuxCNC and import only :mod:`.protocol` and the standard library.
"""
