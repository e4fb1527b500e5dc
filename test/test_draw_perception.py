#!/usr/bin/python3
"""scripts/draw_perception.py draws a superquadric where the camera sees it whatever frame the
perception published its markers in: a bag whose ~markers and ~objects are in the table frame and
one whose are in another output frame (table_in_frame turned and shifted) give the same picture,
and the triangle lands where the camera model puts it.

Usage: test_draw_perception.py SCRIPTS_DIR   (with the devel space sourced, for simstack's messages)
"""
import math
import os
import subprocess
import sys
import tempfile

import matplotlib

matplotlib.use("Agg")
import matplotlib.image as mpimg  # noqa: E402
import numpy as np  # noqa: E402
import rosbag  # noqa: E402
import rospy  # noqa: E402
from geometry_msgs.msg import Point, Pose  # noqa: E402
from sensor_msgs.msg import CameraInfo, Image  # noqa: E402
from simstack.msg import ObjectArray  # noqa: E402
from visualization_msgs.msg import Marker, MarkerArray  # noqa: E402

W, H, F = 64, 48, 50.0  # image size and focal length (pixels)


def pose(x, y, z, yaw):
    p = Pose()
    p.position.x, p.position.y, p.position.z = x, y, z
    p.orientation.w, p.orientation.z = math.cos(yaw / 2), math.sin(yaw / 2)
    return p


def write_bag(path, T_frame_table):
    """One frame: the camera is the table frame (optical axes), a triangle 1 m ahead of it,
    published in the frame where the table lies at T_frame_table (x, y, z, yaw)."""
    stamp = rospy.Time(10)
    depth = Image(height=H, width=W, encoding="32FC1", step=4 * W,
                  data=np.full((H, W), 1.0, np.float32).tobytes())
    depth.header.stamp = stamp
    info = CameraInfo(height=H, width=W, K=[F, 0, W / 2, 0, F, H / 2, 0, 0, 1])
    info.header.stamp = stamp
    labels = Image(height=H, width=W, encoding="mono16", step=2 * W,
                   data=np.zeros((H, W), np.uint16).tobytes())
    labels.header.stamp = stamp
    objects = ObjectArray(table_pose=pose(0, 0, 0, 0), table_in_frame=pose(*T_frame_table))
    objects.header.stamp = stamp
    marker = Marker(ns="superquadrics", id=0, type=Marker.TRIANGLE_LIST, pose=pose(*T_frame_table))
    marker.header.stamp = stamp
    marker.color.r, marker.color.a = 1.0, 1.0
    marker.points = [Point(-0.2, -0.15, 1.0), Point(0.2, -0.15, 1.0), Point(0.0, 0.2, 1.0)]
    with rosbag.Bag(path, "w") as bag:
        for topic, msg in (("/camera/depth/image_rect", depth), ("/camera/depth/camera_info", info),
                           ("/camera/perception/labels", labels),
                           ("/camera/perception/objects", objects),
                           ("/camera/perception/markers", MarkerArray(markers=[marker]))):
            bag.write(topic, msg, stamp)


def draw(script, bag, out):
    subprocess.run([sys.executable, script, bag, "--output", out], check=True,
                   stdout=subprocess.DEVNULL)
    return mpimg.imread(os.path.join(out, "superquadrics_over_depth.png"))[:, :, :3]


def main():
    script = os.path.join(sys.argv[1], "draw_perception.py")
    with tempfile.TemporaryDirectory() as tmp:
        pictures = []
        for name, T in (("table", (0, 0, 0, 0)), ("other", (1.0, 0.5, 0.2, math.pi / 2))):
            write_bag(os.path.join(tmp, name + ".bag"), T)
            pictures.append(draw(script, os.path.join(tmp, name + ".bag"), os.path.join(tmp, name)))
        # Red over grey where the triangle is: its centroid (0, -0.033, 1) projects to pixel
        # (32, 22.3); the image corner stays grey.
        red = pictures[0][:, :, 0] - pictures[0][:, :, 1]
        assert red[22, 32] > 0.3 and red[2, 2] < 0.05, (red[22, 32], red[2, 2])
        diff = np.abs(pictures[0] - pictures[1]).max()
        assert diff < 1e-6, "the output frame's picture differs from the table frame's by %g" % diff
    print("draw_perception: the same picture from markers in the table frame and in another frame")


if __name__ == "__main__":
    main()
