"""Imported first by the campaign's forkserver, before numpy: one BLAS/OpenMP thread per
worker (workers are forked from that server and keep its thread pools), so two trials on
two cores do not fight over four threads whatever the parent's environment says."""

import os

from bench.campaign.execute import THREAD_ENV

for _name, _value in THREAD_ENV.items():
    os.environ.setdefault(_name, _value)
