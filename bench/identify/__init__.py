"""Servo identification: fit each joint's servo physics (friction, armature, motor constant) to the
rig's own trial logs, by simulating every joint through the shared servo model along the measured
configuration, and write the servo model file the simulator runs. The test stand's identification
is the stand's own (bench.stand); both search with the one fitting loop, bench.core.search."""
