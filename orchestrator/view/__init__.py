"""Seeing a run: plots from the log, Foxglove views, live views, ROS 2 mirror."""
