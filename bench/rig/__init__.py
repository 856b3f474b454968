"""Which backend a trial runs on: the PyBullet or Dynamixel actuators built from a config, and the
emulated rig (servo bus and ultrasonic sensor on pseudo-terminals) that stands in for the lab."""
