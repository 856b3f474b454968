"""``hilbench``: the command line, one module per feature over the library; shared helpers in
:mod:`bench.cli.common`. The top of the layers: nothing in the library imports it."""
