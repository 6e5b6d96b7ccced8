"""Sessions: recording the graph to rosbag2 MCAP folders, reading them back, replaying them."""
