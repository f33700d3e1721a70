"""The SimpleTrack streaming service: Zenoh intake, per-sensor workers, snapshots, metrics.

Needs the ``service`` extra (pydantic-settings, prometheus-client, pyyaml).
"""
