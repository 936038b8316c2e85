"""`roi-node check-calibration`: camera delay and reprojection offsets measured from a bag's own images."""
