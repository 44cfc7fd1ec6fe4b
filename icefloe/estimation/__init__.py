"""Estimating where the robot and the landmarks are, pure logic with no bus, shared by the
odometry, localizer, SLAM and map-making services: dead reckoning (`odometry`), the map-based
EKF (`ekf`) and its bookkeeping between messages (`localizer`), marker blocks (`blocks`), landmark
sightings and maps (`landmarks`), and the square runs that measure them (`simrun`)."""
