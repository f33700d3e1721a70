"""Benchmarks of the tracker core and of the running service (``simpletrack bench``).

``core``: the tracker alone on nuScenes, KITTI and synthetic frames (docs/BENCHMARKS.md).
``service``: ``simpletrack serve`` under a load generator over Zenoh on 127.0.0.1.
"""
