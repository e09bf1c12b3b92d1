"""Lab recordings in: OpenSim/TRC/C3D files -> observation bags of the planar jumper."""
