"""featmap: fuse redundant wall features from LiDAR drives into a compact 2D line map.

The package is organised the way one scan travels through it::

    datasets/    KITTI raw drives (and simulated ones): points, T_w_velo, timestamp
    extraction/  vertical planes of one scan -> 2D ground segments
    fusion/      the paper's method and its two competitors (a registry by name)
    evaluation   map-quality metrics against ground-truth footprints
    io/          CSV / GeoJSON / KML / HTML readers and writers (atomic)
    pipeline     the loop that ties them together and owns the run folder
    simulation/  a ray-casting LiDAR simulator that writes KITTI raw drives
"""

__version__ = "0.1.0"
