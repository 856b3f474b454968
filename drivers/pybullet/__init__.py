"""The PyBullet backend: the robot's joints in a private physics world behind ``Actuators``."""
