#!/usr/bin/python3
"""Pictures of what the perception node published, from a bag recorded by scripts/demo:
the instances (the ~labels image) and the superquadrics (the ~markers, projected with the
camera_info and the table pose of ~objects) over the depth image of the same frame.

    scripts/draw_perception.py perception.bag --output DIR
"""
import argparse
import os
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import rosbag  # noqa: E402
from matplotlib.collections import PolyCollection  # noqa: E402


def quat_matrix(q):
    w, x, y, z = q.w, q.x, q.y, q.z
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def pose_matrix(pose):
    T = np.eye(4)
    T[:3, :3] = quat_matrix(pose.orientation)
    T[:3, 3] = [pose.position.x, pose.position.y, pose.position.z]
    return T


def image_array(msg):
    dtypes = {"16UC1": np.uint16, "mono16": np.uint16, "32FC1": np.float32}
    if msg.encoding not in dtypes:
        raise ValueError("an image of encoding %s (16UC1, mono16 or 32FC1 expected)" % msg.encoding)
    dtype = dtypes[msg.encoding]
    a = np.frombuffer(msg.data, dtype=dtype).reshape(msg.height, msg.step // np.dtype(dtype).itemsize)
    return a[:, :msg.width].astype(np.float32)


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("bag", help="the bag recorded from the perception's topics")
    parser.add_argument("--output", default=".", help="directory of the two PNGs (default: .)")
    parser.add_argument("--camera", default="camera",
                        help="the camera's namespace in the bag (default: camera)")
    args = parser.parse_args()
    topics = {f"/{args.camera}/depth/image_rect": "depth", f"/{args.camera}/depth/camera_info": "info",
              f"/{args.camera}/perception/objects": "objects", f"/{args.camera}/perception/markers": "markers",
              f"/{args.camera}/perception/labels": "labels"}

    def stamp_of(kind, msg):  # nanoseconds, or None
        stamp = msg.markers[0].header.stamp if kind == "markers" and msg.markers else \
            getattr(msg, "header", None) and msg.header.stamp
        return None if stamp is None else stamp.to_nsec()

    # One pass that holds only the last complete frame and the stamps after it: a long bag's
    # images are not all kept.
    frames, last = {}, None  # stamp -> kind -> message; the last stamp with all five kinds
    try:
        with rosbag.Bag(args.bag) as bag:
            for topic, msg, _ in bag.read_messages(topics=list(topics)):
                stamp = stamp_of(topics[topic], msg)
                if stamp is None or (last is not None and stamp < last):
                    continue
                frames.setdefault(stamp, {})[topics[topic]] = msg
                if len(frames[stamp]) == 5 and stamp != last:
                    last = stamp
                    frames = {s: f for s, f in frames.items() if s >= last}
    except rosbag.ROSBagException as e:  # its message does not name the file
        sys.exit(f"draw_perception: {args.bag}: {e}")
    if last is None:
        sys.exit(f"draw_perception: {args.bag} holds no frame with depth, camera_info, objects, markers and labels")
    frame = frames[last]
    when = f"{args.bag}, the frame stamped {last / 1e9:.3f} s"
    depth = image_array(frame["depth"]) * (0.001 if frame["depth"].encoding != "32FC1" else 1.0)
    depth[~np.isfinite(depth)] = 0.0
    labels = image_array(frame["labels"]).astype(int)
    if not (depth > 0).any():
        sys.exit(f"draw_perception: {when}: its depth image holds no valid depth")
    if labels.shape != depth.shape:
        sys.exit(f"draw_perception: {when}: its labels image is {labels.shape[1]}x{labels.shape[0]}, "
                 f"its depth image {depth.shape[1]}x{depth.shape[0]}")
    colours = {m.id + 1: (m.color.r, m.color.g, m.color.b) for m in frame["markers"].markers
               if m.ns == "superquadrics"}
    grey = np.where(depth > 0, 1.0 - np.clip((depth - depth[depth > 0].min()) / (np.ptp(depth[depth > 0]) + 1e-6), 0, 1) * 0.7, 0)
    base = np.dstack([grey] * 3)
    os.makedirs(args.output, exist_ok=True)

    painted = base.copy()
    for label, c in colours.items():
        painted[labels == label] = 0.35 * base[labels == label] + 0.65 * np.array(c)
    out1 = os.path.join(args.output, "instances_over_depth.png")
    plt.imsave(out1, painted)

    K = np.array(frame["info"].K).reshape(3, 3)
    # The markers lie in the output frame: T_camera_frame = T_camera_table inv(T_frame_table),
    # table_in_frame the identity (or unset) when that is the table frame.
    T_camera_table = pose_matrix(frame["objects"].table_pose)
    q = frame["objects"].table_in_frame.orientation
    T_frame_table = np.eye(4) if (q.w, q.x, q.y, q.z) == (0, 0, 0, 0) else \
        pose_matrix(frame["objects"].table_in_frame)
    T_camera_frame = T_camera_table @ np.linalg.inv(T_frame_table)
    fig = plt.figure(figsize=(depth.shape[1] / 100, depth.shape[0] / 100), dpi=100)
    ax = fig.add_axes([0, 0, 1, 1])
    ax.imshow(base)
    # Every object's triangles in one list, drawn far to near, so that a hidden object's stay
    # behind the one in front of it.
    tris, depths, faces = [], [], []
    for m in frame["markers"].markers:
        if m.ns != "superquadrics":
            continue
        pts = np.array([[p.x, p.y, p.z, 1.0] for p in m.points]).T
        cam = (T_camera_frame @ pose_matrix(m.pose) @ pts)[:3]
        uv = (K @ cam)[:2] / np.maximum(cam[2], 1e-6)
        tris.append(uv.T.reshape(-1, 3, 2))
        depths.append(cam[2].reshape(-1, 3).mean(axis=1))
        faces += [(*colours[m.id + 1], 0.55)] * len(tris[-1])
    if tris:
        order = np.argsort(-np.concatenate(depths))
        ax.add_collection(PolyCollection(np.concatenate(tris)[order],
                                         facecolors=[faces[i] for i in order], edgecolors="none"))
    ax.set_xlim(0, depth.shape[1])
    ax.set_ylim(depth.shape[0], 0)
    ax.axis("off")
    out2 = os.path.join(args.output, "superquadrics_over_depth.png")
    fig.savefig(out2)
    print(out1)
    print(out2)


if __name__ == "__main__":
    try:
        main()
    except (OSError, ValueError, UnicodeDecodeError, rosbag.ROSBagException) as e:
        sys.exit(f"draw_perception: {e}")
