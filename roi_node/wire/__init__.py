"""The ROS message contract: topic names, image codec, compressed outputs, overlay CDR, rosbags messages."""
