"""navkit: the method-agnostic toolkit every navigation system of the benchmark is built from.

SE(2) poses (``geometry``), one grid frame and ROS map_server files (``raster``), grid search and
planning (``grid_search``, ``grid_planning``), the shared path follower (``follower``), lidar
odometry (``odometry``), obstacles remembered beyond the map (``obstacles``), the lidar cloud's
obstacle band and ray tracing (``scan``), the data passed between the runner and systems
(``types``) and crash-safe files (``files``). NavTopo (``navtopo``), the metric baseline
(``baselines.metric_grid``), the oracle and the scenarios all import it; it imports none of them.
"""
