"""The identified robot where it is used: MJCF for MuJoCo, URDF/SDFormat for Drake and ROS,
controller feed-forward, PD gains and randomization ranges (``pe-drake export``)."""
