"""The metric SLAM baseline (DESIGN.md): kiss-icp odometry, a gtsam pose graph with verified loop
closures, a global 0.1 m log-odds grid saved as a ROS map_server map, and Theta* on that grid.

Parts, each testable alone with arrays in and arrays out (``system.MetricGrid`` composes them):

* ``config``      ``MetricGridConfig`` (one small model per part), ``SETTING_OVERRIDES``, ``for_context``
* ``scan2d``      the lean 2D keyframe scan: voxel-filtered obstacle points and free ranges
* ``pose_graph``  ``PoseGraph``: keyframes, loop closures, iSAM2 / Levenberg-Marquardt, save/load
* ``occupancy``   ``OccupancyGrid`` (log-odds, growing bounds), ``GridMap`` (map_server PGM + YAML),
                  ``map_quality`` against a ground-truth raster
* ``map_folder``  the saved map folder: the map, the pose graph, the manifest; ``MetricMapError``
* ``localization`` ``ScanToMap`` (scan-to-map registration), ``Relocalizer`` (correlative search)
* ``tracking``    ``PoseTracker``: the map-frame pose while navigating (odometry, fits, relocalization)
* ``obstacles``   ``UnmappedObstacles``: returns the map lacks, remembered until seen through
* ``planning``    ``GridPlanner``: Theta* on the eroded free cells, its fallbacks, new obstacles blocked

The odometry is the shared ``navkit.odometry.LidarOdometry`` (kiss-icp, optionally seeded by wheel
odometry); the follower is the shared ``navkit.follower.PathFollower``.
"""
