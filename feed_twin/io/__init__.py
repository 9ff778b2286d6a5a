"""Files at the edges: YAML configs, measured CSV, rosbag2 MCAP recordings, Rerun recordings."""
