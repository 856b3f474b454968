"""A trial's log in formats other robotics tools open (MCAP with ROS 2 messages)."""
