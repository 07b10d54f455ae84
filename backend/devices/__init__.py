"""Sensor drivers behind the one capture interface in :mod:`backend.devices.base`.

Importing the package registers every built-in driver with :func:`backend.devices.base.create_device`. Drivers
never import simulators: the simulated drivers, and the simulated endpoints that ``port="sim"``, ``host="sim"``
and ``servo_port="sim"`` start, are registered by :data:`backend.devices.base.SIMULATORS_MODULE` when imported.
"""

from backend.devices import (  # noqa: F401
    cloud_files,
    depth_files,
    dynamixel_servo,
    hokuyo,
    image_folder,
    kinect2,
    livox,
    lvx_file,
    node_network,
    realsense,
    rosbag_source,
    uvc_camera,
    vectornav,
    velodyne,
    ydlidar,
)
