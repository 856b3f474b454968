"""The ROS 2 message definitions an exported trial uses, as rosbag2 writes them into MCAP.

Each definition is followed by the definitions it uses, separated by a line of
``=`` and ``MSG: package/Name``: the form Foxglove, PlotJuggler and the
``mcap`` ROS 2 decoder read without a ROS installation.
"""

from __future__ import annotations

__all__ = ["JOINT_STATE", "FLOAT64", "STRING", "LOG", "LOG_LEVEL", "POINT_STAMPED"]

_SEP = "=" * 80
_TIME = "MSG: builtin_interfaces/Time\nint32 sec\nuint32 nanosec\n"
_HEADER = "MSG: std_msgs/Header\nbuiltin_interfaces/Time stamp\nstring frame_id\n"

#: ``sensor_msgs/msg/JointState``: positions (rad or m), velocities (rad/s or m/s), efforts (N·m or N).
JOINT_STATE = ("sensor_msgs/msg/JointState",
               "std_msgs/Header header\nstring[] name\nfloat64[] position\nfloat64[] velocity\n"
               f"float64[] effort\n{_SEP}\n{_HEADER}{_SEP}\n{_TIME}")

FLOAT64 = ("std_msgs/msg/Float64", "float64 data\n")

#: ``geometry_msgs/msg/PointStamped``: a point (m) in ``header.frame_id``'s frame at its stamp.
POINT_STAMPED = ("geometry_msgs/msg/PointStamped",
                 f"std_msgs/Header header\ngeometry_msgs/Point point\n{_SEP}\n{_HEADER}{_SEP}\n{_TIME}"
                 f"{_SEP}\nMSG: geometry_msgs/Point\nfloat64 x\nfloat64 y\nfloat64 z\n")

STRING = ("std_msgs/msg/String", "string data\n")

#: ``rcl_interfaces/msg/Log``: what ``/rosout`` carries; the trial's events go there.
LOG = ("rcl_interfaces/msg/Log",
       "byte DEBUG=10\nbyte INFO=20\nbyte WARN=30\nbyte ERROR=40\nbyte FATAL=50\n"
       "builtin_interfaces/Time stamp\nuint8 level\nstring name\nstring msg\nstring file\n"
       f"string function\nuint32 line\n{_SEP}\n{_TIME}")

#: The ``/rosout`` level of each kind of trial event (anything else is INFO).
LOG_LEVEL = {"interlock": 40, "abort": 40, "safe-stop": 30, "hold": 30, "fault": 30}
