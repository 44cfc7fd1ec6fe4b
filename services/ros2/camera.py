"""The camera's topics as ROS 2 messages: its JPEGs (``camera/image_raw/compressed``), their
intrinsics (``camera/camera_info``, stamped as the image they go with) and the markers it found
(``camera/landmarks``). The camera frame is OpenCV's axes (x right, y down, z forward): ROS's
optical frame (REP 103)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from icefloe import ros2
from icefloe.config import Camera
from icefloe.schemas import messages as m
from icefloe.vision.geometry import Intrinsics

from .stamped import Builder

COMPRESSED_IMAGE = "sensor_msgs/msg/CompressedImage"
CAMERA_INFO = "sensor_msgs/msg/CameraInfo"
MARKER_ARRAY = "visualization_msgs/msg/MarkerArray"

MARKER_THICKNESS = 0.005
"""Of the square drawn for a marker, m (a printed marker is flat; RViz needs some thickness)."""


class CompressedImage:
    """``camera/image`` or ``camera/frames`` (JPEG) as CompressedImage: the same bytes, not decoded."""

    def __init__(self, distro: ros2.Distro, frame: str) -> None:
        self.b, self.frame = Builder(distro), frame

    def message(self, image: m.Image) -> Any:
        return self.b.t[COMPRESSED_IMAGE](header=self.b.header(image.stamp, self.frame), format=image.format,
                                          data=np.frombuffer(image.data, dtype=np.uint8))


class CameraInfo:
    """The intrinsics of each image, stamped as the image is (image_proc and RViz pair the two by
    stamp). From the robot config's calibration (``camera.calibration``, else ``focal_px``), made at
    the capture size and scaled to the image's, as the camera scales them for ``camera/info``.

    The distortion model is ``plumb_bob`` for OpenCV's 4 or 5 coefficients (k1, k2, p1, p2, k3;
    4 padded with k3 = 0), ``rational_polynomial`` for more (ROS 2 reads its first 8)."""

    def __init__(self, distro: ros2.Distro, frame: str, camera: Camera) -> None:
        self.b, self.frame = Builder(distro), frame
        self.intrinsics = Intrinsics.from_config(camera)  # ConfigError for a bad calibration file, as the camera's
        self._scaled: dict[tuple[int, int], Intrinsics] = {}

    def message(self, image: m.Image) -> Any:
        if image.width <= 0 or image.height <= 0:
            raise ValueError(f"width x height: {image.width} x {image.height}, not a picture")
        size = (image.width, image.height)
        if size not in self._scaled:
            self._scaled = {size: self.intrinsics.scaled(*size)}  # one size at a time: the camera's
        lens = self._scaled[size]
        k = lens.camera_matrix.astype(np.float64)
        d = lens.dist_coeffs.astype(np.float64).ravel()
        model = "plumb_bob" if d.size <= 5 else "rational_polynomial"
        if d.size < 5:
            d = np.concatenate([d, np.zeros(5 - d.size)])
        p = np.hstack([k, np.zeros((3, 1))])  # a monocular camera: P is K with no translation
        t = self.b.t
        roi = t["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
        return t[CAMERA_INFO](header=self.b.header(image.stamp, self.frame), height=image.height,
                              width=image.width, distortion_model=model, d=d, k=k.ravel(),
                              r=np.eye(3).ravel(), p=p.ravel(), binning_x=0, binning_y=0, roi=roi)


class LandmarkMarkers:
    """``camera/landmarks`` as a MarkerArray: each marker seen as a flat square (``Marker.id`` its
    ArUco id, ``ns`` "aruco") in the camera frame, at the pose the camera measured; a landmark
    with no pose (a camera that gives only range and bearing) as a thin cylinder on the floor at
    its range and bearing in the base frame. A DELETEALL first: what a frame did not see goes.

    Why MarkerArray: it keeps the ids (PoseArray has none), every ROS 2 installation has it
    (common_interfaces) and RViz shows it as it comes; vision_msgs is not in rosbags' typestores."""

    def __init__(self, distro: ros2.Distro, camera_frame: str, base_frame: str, marker_size: float) -> None:
        self.b, self.camera_frame, self.base_frame, self.size = Builder(distro), camera_frame, base_frame, marker_size

    def _marker(self, header: Any, kind: int, action: int, marker_id: int = 0, pose: Any = None,
                scale: Any = None) -> Any:
        t = self.b.t
        marker = t["visualization_msgs/msg/Marker"]
        no_image = t[COMPRESSED_IMAGE](header=header, format="", data=np.zeros(0, dtype=np.uint8))
        return marker(header=header, ns="aruco", id=marker_id, type=kind, action=action,
                      pose=pose or self.b.pose(0.0, 0.0, 0.0), scale=scale or self.b.vector(0.0, 0.0, 0.0),
                      color=t["std_msgs/msg/ColorRGBA"](r=0.1, g=0.6, b=1.0, a=0.8),
                      lifetime=t["builtin_interfaces/msg/Duration"](sec=0, nanosec=0), frame_locked=False,
                      points=[], colors=[], texture_resource="", texture=no_image, uv_coordinates=[], text="",
                      mesh_resource="", mesh_file=t["visualization_msgs/msg/MeshFile"](filename="", data=np.zeros(
                          0, dtype=np.uint8)), mesh_use_embedded_materials=False)

    def message(self, found: m.Landmarks) -> Any:
        t, marker = self.b.t, self.b.t["visualization_msgs/msg/Marker"]
        markers = [self._marker(self.b.header(found.stamp, self.camera_frame), marker.CUBE, marker.DELETEALL)]
        for landmark in found.landmarks:
            if not 0 <= landmark.id < 2**31:  # Marker.id is an int32
                raise ValueError(f"landmarks: id {landmark.id} is not an ArUco id (0 to 2^31 - 1)")
            if len(landmark.position) == 3 and len(landmark.rotation) == 3:
                header = self.b.header(found.stamp, self.camera_frame)
                pose = t["geometry_msgs/msg/Pose"](position=self.b.point(*landmark.position),
                                                   orientation=self.b.rotation(landmark.rotation))
                scale = self.b.vector(self.size, self.size, MARKER_THICKNESS)  # the marker's z: its normal
                kind = marker.CUBE
            elif landmark.position or landmark.rotation:
                raise ValueError(f"landmarks: marker {landmark.id}: position and rotation must have 3 numbers "
                                 f"each, not {len(landmark.position)} and {len(landmark.rotation)}")
            else:
                header = self.b.header(found.stamp, self.base_frame)
                pose = self.b.pose(landmark.range * math.cos(landmark.bearing),
                                   landmark.range * math.sin(landmark.bearing), 0.0)
                scale = self.b.vector(self.size, self.size, MARKER_THICKNESS)
                kind = marker.CYLINDER
            markers.append(self._marker(header, kind, marker.ADD, landmark.id, pose, scale))
        return t[MARKER_ARRAY](markers=markers)
