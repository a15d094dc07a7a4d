"""Entry points of the nifo ROS 2 nodes; the nodes themselves are ``nifo_nodes`` (pip package ``nifo``)."""
