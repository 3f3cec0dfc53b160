"""Foxglove's message schemas in their ROS 2 ``.msg`` form (``foxglove_msgs``), and the ROS 2
definitions they use (``builtin_interfaces``, ``geometry_msgs``): the ``ros2msg`` schemas of
the bench's MCAP logs (:mod:`autopilot.mcap_log`).

The field lists are those of Foxglove's own schema files (foxglove-sdk, ``schemas/ros2/*.msg``,
MIT licence, as of 2026-08; comments dropped: the order and types of the fields are what a CDR
reader needs). Foxglove, Lichtblick and PlotJuggler decode a message with the schema the file
carries, so an older viewer reads the newer LocationFix (heading, velocity, colour, metadata)
too. ``MSGS[name]`` is a definition's text by ``pkg/Name``;
:func:`autopilot.ros2msg.schema_text` joins one with its dependencies.
"""

from __future__ import annotations

__all__ = ["MSGS"]

MSGS: dict[str, str] = {
    "builtin_interfaces/Time": """\
int32 sec
uint32 nanosec
""",
    "builtin_interfaces/Duration": """\
int32 sec
uint32 nanosec
""",
    "geometry_msgs/Vector3": """\
float64 x
float64 y
float64 z
""",
    "geometry_msgs/Point": """\
float64 x
float64 y
float64 z
""",
    "geometry_msgs/Quaternion": """\
float64 x
float64 y
float64 z
float64 w
""",
    "geometry_msgs/Pose": """\
geometry_msgs/Point position
geometry_msgs/Quaternion orientation
""",
    "foxglove_msgs/FrameTransforms": """\
foxglove_msgs/FrameTransform[] transforms
""",
    "foxglove_msgs/FrameTransform": """\
builtin_interfaces/Time timestamp
string parent_frame_id
string child_frame_id
geometry_msgs/Vector3 translation
geometry_msgs/Quaternion rotation
""",
    "foxglove_msgs/PoseInFrame": """\
builtin_interfaces/Time timestamp
string frame_id
geometry_msgs/Pose pose
""",
    "foxglove_msgs/LocationFix": """\
builtin_interfaces/Time timestamp
string frame_id
float64 latitude
float64 longitude
float64 altitude
float64[9] position_covariance
uint8 UNKNOWN=0
uint8 APPROXIMATED=1
uint8 DIAGONAL_KNOWN=2
uint8 KNOWN=3
uint8 position_covariance_type
float64 heading
geometry_msgs/Vector3 velocity
foxglove_msgs/Color color
foxglove_msgs/KeyValuePair[] metadata
""",
    "foxglove_msgs/SceneUpdate": """\
foxglove_msgs/SceneEntityDeletion[] deletions
foxglove_msgs/SceneEntity[] entities
""",
    "foxglove_msgs/SceneEntity": """\
builtin_interfaces/Time timestamp
string frame_id
string id
builtin_interfaces/Duration lifetime
bool frame_locked
foxglove_msgs/KeyValuePair[] metadata
foxglove_msgs/ArrowPrimitive[] arrows
foxglove_msgs/CubePrimitive[] cubes
foxglove_msgs/SpherePrimitive[] spheres
foxglove_msgs/CylinderPrimitive[] cylinders
foxglove_msgs/LinePrimitive[] lines
foxglove_msgs/TriangleListPrimitive[] triangles
foxglove_msgs/TextPrimitive[] texts
foxglove_msgs/ModelPrimitive[] models
""",
    "foxglove_msgs/SceneEntityDeletion": """\
builtin_interfaces/Time timestamp
uint8 MATCHING_ID=0
uint8 ALL=1
uint8 type
string id
""",
    "foxglove_msgs/CubePrimitive": """\
geometry_msgs/Pose pose
geometry_msgs/Vector3 size
foxglove_msgs/Color color
""",
    "foxglove_msgs/CylinderPrimitive": """\
geometry_msgs/Pose pose
geometry_msgs/Vector3 size
float64 bottom_scale
float64 top_scale
foxglove_msgs/Color color
""",
    "foxglove_msgs/LinePrimitive": """\
uint8 LINE_STRIP=0
uint8 LINE_LOOP=1
uint8 LINE_LIST=2
uint8 type
geometry_msgs/Pose pose
float64 thickness
bool scale_invariant
geometry_msgs/Point[] points
foxglove_msgs/Color color
foxglove_msgs/Color[] colors
uint32[] indices
""",
    "foxglove_msgs/KeyValuePair": """\
string key
string value
""",
    "foxglove_msgs/ArrowPrimitive": """\
geometry_msgs/Pose pose
float64 shaft_length
float64 shaft_diameter
float64 head_length
float64 head_diameter
foxglove_msgs/Color color
""",
    "foxglove_msgs/SpherePrimitive": """\
geometry_msgs/Pose pose
geometry_msgs/Vector3 size
foxglove_msgs/Color color
""",
    "foxglove_msgs/TriangleListPrimitive": """\
geometry_msgs/Pose pose
geometry_msgs/Point[] points
foxglove_msgs/Color color
foxglove_msgs/Color[] colors
uint32[] indices
""",
    "foxglove_msgs/TextPrimitive": """\
geometry_msgs/Pose pose
bool billboard
float64 font_size
bool scale_invariant
foxglove_msgs/Color color
string text
""",
    "foxglove_msgs/ModelPrimitive": """\
geometry_msgs/Pose pose
geometry_msgs/Vector3 scale
foxglove_msgs/Color color
bool override_color
string url
string media_type
uint8[] data
""",
    "foxglove_msgs/Color": """\
float64 r
float64 g
float64 b
float64 a
""",
}
