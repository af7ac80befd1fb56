"""A LiDAR drive simulator: worlds (data) -> ray-cast scans -> a KITTI raw drive with ground truth."""
