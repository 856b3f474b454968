"""HTML reports of a trial: joint profiles, tracking table, events, the robot at its final pose."""
