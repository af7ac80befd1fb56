"""Datasets by name. An item is a :class:`ScanItem`: velodyne points, ``T_w_velo`` and a timestamp."""

from featmap.datasets.base import ScanItem
from featmap.datasets.kitti_raw import KittiRawDataset, parse_drive, parse_frames

DATASETS = {"kitti_raw": KittiRawDataset}

__all__ = ["DATASETS", "KittiRawDataset", "ScanItem", "parse_drive", "parse_frames"]
