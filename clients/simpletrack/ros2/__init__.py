"""The ROS 2 (Autoware) adapter: ``simpletrack bridge ros2``.

Autoware ``DetectedObjects`` arrive as CDR on a Zenoh key (through zenoh-bridge-ros2dds or
rmw_zenoh, ``layout``), become the service's detection frames (``convert``) and go to the
service with the client library; the service's tracks come back as ``TrackedObjects`` CDR on
an output key. ``cdr``/``codec`` read and write the CDR, ``messages`` holds the message types
of ``msg/`` (the .msg definitions, verbatim), ``typehash`` their ROS 2 type hashes, ``labels``
the Autoware label <-> class maps, ``frames`` the extrinsic or pose a fused vehicle's
message goes with, ``bridge`` the process (one sensor, or a fused vehicle's sensors in and its
fused tracks out). docs/ROS2.md has the set-up.

Light: numpy, zenoh and msgpack only, like ``simpletrack.client``.
"""
