"""ros2: the robot's odometry and its drive as ROS 2 topics in rmw_zenoh's form (docs/ros2.md)."""
