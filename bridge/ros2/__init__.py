"""ROS 2 messages of GX3 samples, shared by the archive export and live publishing."""
