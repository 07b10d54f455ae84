"""Sensor drivers behind the one capture interface in :mod:`backend.devices.base`.

Importing the package registers every built-in driver with :func:`backend.devices.base.create_device`.
"""

from backend.devices import (  # noqa: F401
    cloud_files,
    depth_files,
    dynamixel_servo,
    image_folder,
    kinect2,
    node_network,
    realsense,
    rosbag_source,
    simulated_camera,
    simulated_depth,
    simulated_lidar,
    uvc_camera,
    velodyne,
    ydlidar,
)
