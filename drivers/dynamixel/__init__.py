"""The DYNAMIXEL Protocol 2.0 driver: packets, the control table in SI, the bus as the lab tools
see it, the per-cycle sync exchanges and the ``Actuators`` backend for a servo bus."""
