"""Arrays <-> ROS 2 messages: the only place where the two meet."""
