"""Lab-rig tools: find the servos on a bus, check a rig before a trial, calibrate it, jog it.

The library behind ``hilbench scan | doctor | calibrate | jog`` (``bench/cli/lab.py``):

* :mod:`bench.lab.scan` — every servo on a port, at one or every X-series baud rate;
* :mod:`bench.lab.doctor` — pre-trial checks of a config's rig, each pass / warn / fail;
* :mod:`bench.lab.calibrate` — joint zero offsets and the ultrasonic sensor's offset and
  scale, measured with the technician; :mod:`bench.config.calibration` is the file it writes
  and trials load;
* :mod:`bench.lab.jog` — one joint at a time, in small steps within limits, from the keyboard.

Everything works the same against the emulated rig on pseudo-terminals
(:class:`bench.rig.emulated.EmulatedRig`). Raw register units stay in ``drivers/``;
here everything is SI. This package's ``__init__`` imports nothing, so trials can
load calibration files without pulling in the tools.
"""
