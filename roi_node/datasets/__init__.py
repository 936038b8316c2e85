"""Export of ROI bags to LeRobot v3.0 datasets (`roi-node export lerobot`)."""
