"""rosbag2 bags (MCAP storage) to and from :class:`~nifo_core.signal.record.Record`.

Layout of the bags nifo writes (and expects by default)
-------------------------------------------------------
- ``/nifo/spindle/imu``: ``sensor_msgs/msg/Imu``, spindle (unsprung) acceleration
  in ``linear_acceleration.<axis>`` [m/s²];
- ``/nifo/body/imu``: ``sensor_msgs/msg/Imu``, body (sprung) acceleration, likewise;
- ``/nifo/tire_patch/displacement`` (optional): ``geometry_msgs/msg/PointStamped``,
  tire-patch displacement in ``point.<axis>`` [m];
- ``/nifo/force`` (optional): ``geometry_msgs/msg/WrenchStamped``, a measured
  force on the body (a shaker rig's load cell) in ``wrench.force.<axis>`` [N];
  the standard stamped message for a force (what ROS force/torque sensor
  drivers publish), frame_id ``"force"``.

* One message per sample; ``header.stamp`` is the sample time
  ``t0_ns + round(i · 1e9 / fs_hz)`` and is also the bag's log time.
  ``header.frame_id`` is ``"spindle"``, ``"body"`` or ``"tire_patch"``.
* Imu: only ``linear_acceleration.<axis>`` (default ``z``, vertical) carries
  data; everything else is zero. Per REP-145, ``orientation_covariance[0]``
  and ``angular_velocity_covariance[0]`` are -1 ("not provided");
  ``linear_acceleration_covariance`` is all zero ("unknown").
  Values are stored exactly as in the Record: gravity is *not* added, so a
  write/read round trip is bit-exact.
* Tire-patch displacement is a ``geometry_msgs/msg/PointStamped`` (the point's
  ``<axis>`` component, metres). It is a position, not a vector quantity or a
  pose; PointStamped is the smallest standard stamped message that carries a
  position and is understood by every ROS tool (plotjuggler, rviz, ros2 topic
  echo). A bare ``std_msgs/Float64`` has no stamp and was therefore ruled out.
* rosbag2 metadata version 8 with ``storage_identifier: mcap``: the newest
  version that ``ros2 bag`` on Humble (which cannot parse version 9's QoS
  lists) and Jazzy both read. Message definitions are embedded in the MCAP
  schemas, and every topic records its offered QoS profile: the sensor-data
  profile (best effort, volatile, keep last 5), like ``qos_profile_sensor_data``.
  ``custom_data`` holds ``generator: nifo <version>``; ``ros_distro`` is
  ``jazzy``, the distro of the embedded message definitions (rosbags'
  Jazzy typestore), not rosbags' placeholder ``rosbags``.
* Every zstd chunk carries the CRC-32 of its uncompressed records (MCAP's
  ``uncompressed_crc``); readers check it when present, so a damaged chunk
  is a :class:`~nifo_core.errors.CorruptDataError` naming the file and byte
  offset, never silently changed samples.
* The first stamp is the record's ``t0_ns``; a record without one (``t0_ns``
  0, e.g. simulated) starts at the time of writing (``write_bag(start_ns=...)``
  sets it), so no bag claims to start in 1970.

Reading
-------
:func:`read_bag` accepts a bag directory (with ``metadata.yaml``), a single
``.mcap`` file (rosbags reads lone storage files), a directory holding one
``.mcap`` file without metadata, or a ``.db3`` (sqlite3) bag. Topic roles come
from :class:`BagTopics` or, when the default names are absent, from topic
names (see :func:`resolve_topics`).

rosbags opens the bag (metadata, topics, message counts). The messages are
then decoded without a Python object per message: for a single MCAP file
(uncompressed or with zstd/lz4 chunks) the chunk and message indexes locate
every message record and numpy gathers from the decompressed chunks; other
bags (sqlite3, file/message compression, unindexed MCAP) yield their raw CDR
bytes through rosbags' reader, which are concatenated. In both cases the
fixed-layout fields (stamp, one float64) are gathered per group of equally
sized messages, after checking the encapsulation header and the ``frame_id``
length that sets the offsets; a message that does not fit (big-endian, odd
layout) goes through rosbags' generic ``deserialize_cdr``. See
``benchmarks/bench_bag_read.py`` for the speed against the generic path.

Stamps come from ``header.stamp``; only when those are all zero is the bag's
receive (log) time used, and ``meta["stamps"]`` says so.

Modules
-------
The package (issue 57: the bag I/O as a subpackage, as rosbags keeps ``rosbag2/``): private modules, each one
concern — ``_read`` (a whole bag), ``_stream`` (a bag chunk by chunk), ``_topics`` (which topic is which role),
``_write`` (writing), ``_mcap`` (MCAP chunks straight into numpy, CRCs, structure) — and one public module,
:mod:`nifo.io.bag.cdr` (the CDR layout of the three message types, shared with the ROS nodes). Other packages use
the names below only: the import-linter contract ``private_modules`` keeps the ``_`` modules inside
(``.importlinter``). The front door is lazy (``lazy_loader``, as :mod:`nifo_core.signal`'s): rosbags and mcap are
imported when a bag is first read or written, not by every command that imports the loader.
"""

import lazy_loader

__getattr__, __dir__, __all__ = lazy_loader.attach(__name__, submodules=["cdr"], submod_attrs={
    "_read": ["read_bag"],
    "_stream": ["iter_bag_chunks"],
    "_topics": ["BagTopics", "resolve_topics"],
    "_write": ["BAG_VERSION", "TopicData", "write_bag", "write_channels"],
    "_mcap": ["check_structure", "write_chunk_crcs", "chunk_crc_status"],
    "cdr": ["IMU", "POINT_STAMPED", "WRENCH_STAMPED"],
})
