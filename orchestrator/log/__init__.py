"""Run logs: MCAP write and read, replay onto Zenoh, export as a ROS 2 bag."""
