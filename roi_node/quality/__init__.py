"""Quality of ROI bags without ROS: validate, gates, statistics, the report and checksummed manifests."""
