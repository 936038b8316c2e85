"""rosbag2 MCAP storage: the writer, the indexed reader, integrity checks, recover, CRCs, inspect."""
