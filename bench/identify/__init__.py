"""Servo identification: fit each joint's servo physics (friction, armature, motor constant) to the
rig's own trial logs, by simulating every joint through the shared servo model along the measured
configuration, and write the servo model file the simulator runs."""
