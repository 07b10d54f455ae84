"""LiDAR-IMU calibration: the rotation and time offset between a LiDAR and an IMU from the LiDAR's own motion
(scan-to-scan registration) against the gyro."""
