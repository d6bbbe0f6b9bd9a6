"""ROS 1 and ROS 2 bags as episodes on one control-rate time grid.

The configuration is in `rfmp_rl.data.ros.config`, the resampling functions in
`rfmp_rl.data.ros.resample`, the bag reading in `rfmp_rl.data.ros.reader`;
`rfmp_rl.data.rosbag` re-exports the same names.

`read_rosbags` reads ``.bag`` files (ROS 1) and rosbag2 recordings (a folder with
``metadata.yaml``, or a bare ``.db3`` / ``.mcap`` storage file) with ``rosbags==0.11.9``
(``pip install rfmp_rl[data]``); compressed images also need OpenCV (``opencv-python``). A folder
that is no bag itself stands for the bags in it, in name order, one bag each (so a flat folder
of ``.db3`` / ``.mcap`` files is one bag per file; a recording split over several storage files
needs its ``metadata.yaml``). Unfinished recordings (a ``.bag.active`` file; in a folder of
bags, a subfolder of ``.db3`` / ``.mcap`` files without ``metadata.yaml``) are not read: a
`DataError` suggests ``rosbag reindex`` / ``ros2 bag reindex``; with ``skip_bad`` they are
listed in ``manifest.skipped``. A `RosbagConfig` maps topics to episode keys::

    rate_hz: 10                # the control rate every stream is resampled to
    topics:                    # one key per topic
      /robot/ee_pose: {key: ee_pose}                    # PoseStamped / Pose / TransformStamped
      /joint_states:  {key: joints, field: position}    # JointState position|velocity|effort
      /camera/image:  {key: image}                      # Image rgb8 / bgr8 / mono8
      /camera/compressed: {key: wrist}                  # CompressedImage (jpeg, png)
      /gripper:       {key: gripper}                    # Float32 / Float64 / Bool
    action: [/cmd_pose, /gripper_cmd]     # one flat float32 vector from several topics
    action_manifold: R3 x S3 x R1         # optional: checked against the flat layout
    observation: {state: [/ee_pose, {topic: /joint_states, field: velocity}]}
    time_reference: action     # optional: this key's first/last stamps bound the episode
    segment:
      topic: /episode_marker   # std_msgs/Bool (True = start) or std_msgs/String "start" / "end"
    max_gap_s: 0.5             # optional: the longest a stream may go without a message
    on_gap: error              # or split

Unknown fields are refused (`DataError` listing the allowed ones, `CONFIG_FIELDS`).

**Time.** A message's time is its ``header.stamp`` when the type has a header and the stamp is
non-zero, else the time the bag recorded it. Within each topic, messages are ordered by that
time (stable, so ties keep recording order) and of several messages with the same time the last
one recorded is used.

**Episodes.** Without ``segment`` one bag is one episode. With it, the marker topic's messages
(always timed by their record time: Bool and String have no header) act as a recording switch:
an episode spans from a start marker (``True`` / ``"start"``) to the next end marker
(``False`` / ``"end"``); repeated markers of the current state are ignored, so markers may be
published once per edge or continuously; a start without an end is an error. Only messages
timed inside ``[start, end]`` belong to the episode.

**Grid.** By default an episode covers the overlap of all its streams, ``[max first stamp,
min last stamp]``; with ``time_reference`` it covers that key's span (for a flat vector: the
overlap of its topics), and the other streams are held at their first/last value outside their
own span. The grid is ``t0, t0 + 1/rate, ...`` up to the end of the span (both ends included
when they fall on the grid). Values on it are:

* vectors (positions, joint values, scalars): linear interpolation (`resample_linear`);
* orientations: normalised, made hemisphere-continuous (``q_k -> -q_k`` when its dot product
  with ``q_{k-1}`` is negative, `rfmp_rl.manifolds.quaternion.hemisphere_continuous`), slerped
  (`resample_slerp`), then the whole episode's sign is chosen so that ``w >= 0`` at its first
  step — so a sign flip in the recording, or an episode recorded as ``-q``, disappears
  (`rfmp_rl.data.quaternions`; ``raw_quaternion_signs`` / ``--raw-quaternion-signs`` keeps the
  first sample's recorded sign). This applies to pose orientations under ``topics`` and in
  flat vectors alike; ``Manifest.extra["quaternions"]`` lists the fields and counts the
  episodes negated;
* images and bools: the nearest message in time (`nearest_indices`, ties to the earlier one).

**Gaps.** A stream that goes longer than ``max_gap_s`` without a message inside the recording's
span — between two messages, before its first message (a late start) or after its last (an
early end) — is a gap. The span is the time reference's, else from the first message of any
stream to the last. ``max_gap_s`` defaults to the larger of 0.5 s and 3 grid periods (raise it
for topics published only on change). ``on_gap: error`` (default) raises a `DataError` naming
the bag, topic, episode and the gap's start, end and length; ``on_gap: split`` cuts the
episode at every gap into the parts ``name~0``, ``name~1``, ... where all streams have data and
lists each gap in ``Manifest.gaps`` (a part too short to hold every stream is listed in
``Manifest.skipped``). Shorter gaps are interpolated over as above.

**Keys, shapes and dtypes.** A key ``"a/b"`` becomes the nested key ``("a", "b")``. Per step:

* ``timestamp``: float64 ``()``, seconds since the episode's first step (the grid);
* poses under ``topics``: ``(key, "position")`` float32 ``(3,)`` and ``(key, "orientation")``
  float32 ``(4,)``, a unit quaternion in xyzw order — ROS's order and the S^3 convention of
  `rfmp_rl.manifolds` (identity ``(0, 0, 0, 1)``) — interpolated in float64;
* JointState ``field`` (default ``position``), Float32/Float64 and Float32/Float64MultiArray:
  float32 ``(D,)`` (``(1,)`` for scalars);
* Bool: bool ``(1,)``;
* Image: uint8 ``(H, W, 3)`` RGB (``bgr8`` is converted), ``mono8`` -> ``(H, W, 1)``;
* CompressedImage: decoded by OpenCV to uint8 RGB ``(H, W, 3)`` (grey -> ``(H, W, 1)``, alpha
  dropped). Only the frames the grid uses are decoded.
* flat vectors: ``action: [topics]`` -> ``action``, ``observation: [topics]`` ->
  ``observation``, ``observation: {name: [topics]}`` -> ``("observation", name)``: float32
  ``(D,)``, the topics' values resampled as above and concatenated in list order — a pose is 7
  values (x, y, z, qx, qy, qz, qw), a Bool is 1.0/0.0, no images. An entry is a topic name or
  ``{topic, field, joints}``; a topic may feed several keys but is read one way.
  ``action_manifold`` / ``observation_manifold`` (a string, or ``{name: string}`` for the
  mapping form) are parsed by `rfmp_rl.manifolds.parse_manifold` and must match the layout,
  where orientations are ``S3`` and all else is ``R`` (``"R3 x S3 x R1"`` for a pose and a
  gripper). ``Manifest.extra["vectors"]`` lists each vector's columns per topic.

**JointState names.** Messages may list the joints in another order than the first message;
they are reordered by name. With ``joints: [j1, j2]`` the topic yields those joints in that
order, and messages that do not name all of them (another publisher on the same topic) are
skipped and counted in the manifest (``extra["topics"][topic]["skipped"]``).

**Errors.** Every problem raises `rfmp_rl.data.episodes.DataError` naming the bag and, where
known, the topic, key and episode: a missing path, a configured topic absent from a bag (the
message lists the bag's topics), an unsupported message type, an unreadable or truncated bag,
NaN/inf in a message (``step`` is then the message's index on its topic, counted from 0 in
recording order), a stream without messages in an episode or without time overlap with the
others, a gap (``on_gap: error``), a flat layout that does not match its declared manifold, an
unsupported image encoding and an undecodable compressed image. With ``skip_bad=True`` a bag
that raises is skipped and listed in ``Manifest.skipped`` instead.

The `rfmp_rl.data.episodes.Manifest` has format ``"ros1"`` or ``"ros2"`` (``"ros1+ros2"`` when
given both), ``gaps`` and ``skipped`` as above, and ``extra`` holds the files, the
configuration, the gap limit used, each topic's message types and the number of messages read
from it, and each episode's ``[first, last]`` grid stamp in nanoseconds.
"""

from rfmp_rl.data.ros.config import (
    CONFIG_FIELDS,
    ON_GAP,
    TIMESTAMP,
    RosbagConfig,
    TopicConfig,
    VectorPart,
    load_rosbag_config,
)
from rfmp_rl.data.ros.reader import read_rosbags
from rfmp_rl.data.ros.resample import nearest_indices, resample_linear, resample_slerp, slerp

__all__ = [
    "RosbagConfig",
    "TopicConfig",
    "VectorPart",
    "CONFIG_FIELDS",
    "ON_GAP",
    "TIMESTAMP",
    "load_rosbag_config",
    "read_rosbags",
    "slerp",
    "resample_linear",
    "resample_slerp",
    "nearest_indices",
]
