"""The metric SLAM baseline (DESIGN.md): kiss-icp odometry, a gtsam pose graph with verified loop
closures, a global 0.1 m log-odds grid saved as a ROS map_server map, and Theta* on that grid.

Parts, each testable alone with arrays in and arrays out:

* ``odometry``   ``LidarOdometry`` (kiss-icp, optionally seeded by wheel odometry), ``OdometryConfig``
* ``scan2d``     the lean 2D keyframe scan: voxel-filtered obstacle points and free ranges
* ``pose_graph`` ``PoseGraph``: keyframes, loop closures, iSAM2 / Levenberg-Marquardt, save/load
* ``occupancy``  ``OccupancyGrid`` (log-odds, growing bounds), ``GridMap`` (map_server PGM + YAML),
                 ``map_quality`` against a ground-truth raster
"""
