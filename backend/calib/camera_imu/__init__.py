"""Camera-IMU calibration: the rotation, translation and time offset between a camera and an IMU from a board
waved in front of the camera, fitted as Kalibr's ``kalibr_calibrate_imu_camera`` does (a continuous-time trajectory,
the IMU's rates and specific forces as measurements, its biases estimated)."""
