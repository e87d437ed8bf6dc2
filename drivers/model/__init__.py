"""The robot model: the sans-I/O codec, kinematics, settings, the URDF and ROS 2 messages, checked
numbers and the error types. Importing the package imports none of its modules."""
