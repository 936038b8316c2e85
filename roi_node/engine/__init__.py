"""The pure stream engine: config, camera, kinematics, ROI policy, resampling, sync, stamps, records, errors. No ROS, no bags."""
