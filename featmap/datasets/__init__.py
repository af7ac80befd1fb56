"""Scan sources behind one contract (:class:`ScanSource`), opened by format name (:func:`open_source`)."""

from featmap.datasets.base import Scan, ScanSource, SourceNotes, SourceSpec, parse_frames
from featmap.datasets.kitti_raw import KittiRawDataset, parse_drive
from featmap.datasets.registry import DATASETS, open_source

__all__ = ["DATASETS", "KittiRawDataset", "Scan", "ScanSource", "SourceNotes", "SourceSpec", "open_source",
           "parse_drive", "parse_frames"]
