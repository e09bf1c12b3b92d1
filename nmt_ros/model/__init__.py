"""The planar jumper model: skeleton, contact, muscles, paths, passive joints (no ROS)."""
