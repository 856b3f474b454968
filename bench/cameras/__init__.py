"""The needle seen from outside: the cameras a config asks for, and the metrology above them
(the holder's fiducial found in each view, triangulated to the tip and the needle's direction in
the robot's frame, with an uncertainty). The cameras themselves are drivers (drivers/camera)."""
