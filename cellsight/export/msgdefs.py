"""The ROS 2 message definitions (``.msg`` text) of the types the export writes.

An MCAP file of the ``ros2`` profile carries, per schema, the type's ``.msg`` text followed by
the text of every type it uses, each after a line of 80 ``=`` and a ``MSG: pkg/Type`` line (the
concatenated form that rosbag2 writes and that Foxglove, ``mcap-ros2-support`` and ``rosbags``
read). The texts below are those of ROS 2 Humble and Jazzy (``ros2/common_interfaces``,
``ros2/geometry2``, ``ros2/rcl_interfaces``), their comments left out; field order and types
are what the CDR encoding follows, so they must not be edited.
"""

from __future__ import annotations

MSG: dict[str, str] = {
    "builtin_interfaces/Time": "int32 sec\nuint32 nanosec\n",
    "builtin_interfaces/Duration": "int32 sec\nuint32 nanosec\n",
    "std_msgs/Header": "builtin_interfaces/Time stamp\nstring frame_id\n",
    "std_msgs/ColorRGBA": "float32 r\nfloat32 g\nfloat32 b\nfloat32 a\n",
    "std_msgs/String": "string data\n",
    "geometry_msgs/Vector3": "float64 x\nfloat64 y\nfloat64 z\n",
    "geometry_msgs/Point": "float64 x\nfloat64 y\nfloat64 z\n",
    "geometry_msgs/Quaternion": "float64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1\n",
    "geometry_msgs/Pose": "Point position\nQuaternion orientation\n",
    "geometry_msgs/PoseStamped": "std_msgs/Header header\nPose pose\n",
    "geometry_msgs/PoseWithCovariance": "Pose pose\nfloat64[36] covariance\n",
    "geometry_msgs/PoseWithCovarianceStamped": (
        "std_msgs/Header header\nPoseWithCovariance pose\n"),
    "geometry_msgs/Transform": "Vector3 translation\nQuaternion rotation\n",
    "geometry_msgs/TransformStamped": (
        "std_msgs/Header header\nstring child_frame_id\nTransform transform\n"),
    "tf2_msgs/TFMessage": "geometry_msgs/TransformStamped[] transforms\n",
    "sensor_msgs/RegionOfInterest": (
        "uint32 x_offset\nuint32 y_offset\nuint32 height\nuint32 width\nbool do_rectify\n"),
    "sensor_msgs/CameraInfo": (
        "std_msgs/Header header\nuint32 height\nuint32 width\nstring distortion_model\n"
        "float64[] d\nfloat64[9] k\nfloat64[9] r\nfloat64[12] p\nuint32 binning_x\n"
        "uint32 binning_y\nRegionOfInterest roi\n"),
    "sensor_msgs/Image": (
        "std_msgs/Header header\nuint32 height\nuint32 width\nstring encoding\n"
        "uint8 is_bigendian\nuint32 step\nuint8[] data\n"),
    "sensor_msgs/CompressedImage": "std_msgs/Header header\nstring format\nuint8[] data\n",
    "sensor_msgs/JointState": (
        "std_msgs/Header header\nstring[] name\nfloat64[] position\nfloat64[] velocity\n"
        "float64[] effort\n"),
    "diagnostic_msgs/KeyValue": "string key\nstring value\n",
    "diagnostic_msgs/DiagnosticStatus": (
        "byte OK=0\nbyte WARN=1\nbyte ERROR=2\nbyte STALE=3\nbyte level\nstring name\n"
        "string message\nstring hardware_id\nKeyValue[] values\n"),
    "diagnostic_msgs/DiagnosticArray": "std_msgs/Header header\nDiagnosticStatus[] status\n",
    "visualization_msgs/UVCoordinate": "float32 u\nfloat32 v\n",
    "visualization_msgs/MeshFile": "string filename\nuint8[] data\n",
    "visualization_msgs/Marker": (
        "int32 ARROW=0\nint32 CUBE=1\nint32 SPHERE=2\nint32 CYLINDER=3\nint32 LINE_STRIP=4\n"
        "int32 LINE_LIST=5\nint32 CUBE_LIST=6\nint32 SPHERE_LIST=7\nint32 POINTS=8\n"
        "int32 TEXT_VIEW_FACING=9\nint32 MESH_RESOURCE=10\nint32 TRIANGLE_LIST=11\n"
        "int32 ARROW_STRIP=12\nint32 ADD=0\nint32 MODIFY=0\nint32 DELETE=2\nint32 DELETEALL=3\n"
        "std_msgs/Header header\nstring ns\nint32 id\nint32 type\nint32 action\n"
        "geometry_msgs/Pose pose\ngeometry_msgs/Vector3 scale\nstd_msgs/ColorRGBA color\n"
        "builtin_interfaces/Duration lifetime\nbool frame_locked\n"
        "geometry_msgs/Point[] points\nstd_msgs/ColorRGBA[] colors\nstring texture_resource\n"
        "sensor_msgs/CompressedImage texture\nUVCoordinate[] uv_coordinates\nstring text\n"
        "string mesh_resource\nMeshFile mesh_file\nbool mesh_use_embedded_materials\n"),
    "visualization_msgs/MarkerArray": "Marker[] markers\n",
    "visualization_msgs/ImageMarker": (
        "int32 CIRCLE=0\nint32 LINE_STRIP=1\nint32 LINE_LIST=2\nint32 POLYGON=3\nint32 POINTS=4\n"
        "int32 ADD=0\nint32 REMOVE=1\nstd_msgs/Header header\nstring ns\nint32 id\nint32 type\n"
        "int32 action\ngeometry_msgs/Point position\nfloat32 scale\n"
        "std_msgs/ColorRGBA outline_color\nuint8 filled\nstd_msgs/ColorRGBA fill_color\n"
        "builtin_interfaces/Duration lifetime\ngeometry_msgs/Point[] points\n"
        "std_msgs/ColorRGBA[] outline_colors\n"),
}
"""``pkg/Type`` -> the type's ``.msg`` text (no comments)."""

SEPARATOR = "=" * 80


def _uses(name: str) -> list[str]:
    """The types ``name``'s fields use, ``pkg/Type``, in field order (a bare type name is of
    the same package; arrays and constants counted once)."""
    package = name.split("/")[0]
    found = []
    for line in MSG[name].splitlines():
        kind = line.split()[0].split("[")[0]
        if "=" in line.split()[1] or kind.islower() and "/" not in kind:
            continue  # a constant, or a primitive type
        full = kind if "/" in kind else f"{package}/{kind}"
        if full not in found:
            found.append(full)
    return found


def msgdef(name: str) -> str:
    """The concatenated definition of ``pkg/Type`` (module docstring): its own text, then every
    type it uses, depth first, each once."""
    order: list[str] = []

    def visit(type_name: str) -> None:
        for used in _uses(type_name):
            if used not in order:
                order.append(used)
                visit(used)

    visit(name)
    parts = [MSG[name]] + [f"{SEPARATOR}\nMSG: {used}\n{MSG[used]}" for used in order]
    return "\n".join(parts)


def schema_name(name: str) -> str:
    """The schema name of a message type in a ROS 2 MCAP file: ``pkg/msg/Type``."""
    package, kind = name.split("/")
    return f"{package}/msg/{kind}"
