"""The data the bench ships: the robots' URDFs (``urdf/``) and the configs (``hil_configs/``).

In a checkout they are the top-level ``urdf/`` and ``hil_configs/`` folders, the ones to
edit; a wheel carries them here, as ``bench/data/urdf`` and ``bench/data/hil_configs``
(setup.py maps them in). :mod:`bench.paths` finds them either way.
"""
