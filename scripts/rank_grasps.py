#!/usr/bin/python3
"""Ranks suction grasps on one perceived object through the simstack grasp service and prints
them best first (README, "Grasps").

    scripts/rank_grasps.py --target 0            # an object id of the latest ~objects
    scripts/rank_grasps.py --target top          # the object whose centre is highest
    scripts/rank_grasps.py --target 1 --candidates 32 --hypotheses 3 --json grasps.json
    scripts/rank_grasps.py --point 0.6,0.1,0.05 --point-frame base_link   # nearest this point

The ranking runs as the grasp server's action (feedback with --progress; Ctrl-C cancels it on
the server). The scene is the latest ObjectArray the grasp server received (launch/grasps.launch); with
--target top it is read here first to choose the object (refused when older than --max-age),
and sent with the request, so that the id names the object chosen. Task code calls the same
functions: `from simstack import grasp_client` (src/python/grasp_client.py).
"""
import argparse
import json
import math
import os
import sys
import time

import genpy
import rosgraph
import rospy
from geometry_msgs.msg import PointStamped, PoseStamped, Vector3

try:
    from simstack import grasp_client
except ImportError as e:
    sys.exit("rank_grasps: %s: source the devel (or install) space first, e.g. "
             "source build/devel/setup.bash" % e)


def table(res, rows):
    lines = ["%4s  %-22s %-18s %5s %8s %8s %7s %6s %6s" % (
        "rank", "contact (m, %s)" % (res.grasps[0].tool_pose.header.frame_id if res.grasps else ""),
        "approach", "seal", "mean mm", "max mm", "toppled", "freed", "failed")]
    for i, g in enumerate(res.grasps[:rows]):
        p, a = g.tool_pose.pose.position, g.approach
        lines.append("%4d  %+6.3f %+6.3f %+6.3f  %+5.2f %+5.2f %+5.2f %5.2f %8.1f %8.1f %7.2f %6.2f %6.2f" % (
            i + 1, p.x, p.y, p.z, a.x, a.y, a.z, g.seal_score, 1e3 * g.mean_displacement_m,
            1e3 * g.max_displacement_m, g.toppled, g.freed_share, g.failed_share))
    if len(res.grasps) > rows:
        lines.append("  ... %d more" % (len(res.grasps) - rows))
    # One per scene pulled in: the hypotheses, then the server's perturbed copies.
    for h, d in enumerate(res.baseline_displacement_m):
        line = "baseline (scene %d left alone): objects moved %.1f mm at most" % (h, 1e3 * d)
        if h < len(res.settle_displacement_m) and res.settle_displacement_m[h] > 0.005:
            line += "; while settling, up to %.0f mm" % (1e3 * res.settle_displacement_m[h])
        lines.append(line)
    return "\n".join(lines)


def pose_list(pose):
    """[x, y, z, qw, qx, qy, qz] of a geometry_msgs/Pose."""
    p, q = pose.position, pose.orientation
    return [p.x, p.y, p.z, q.w, q.x, q.y, q.z]


def plain(value):
    """A message field as JSON: poses as [x, y, z, qw, qx, qy, qz] (with a stamped pose's frame
    left to the caller), vectors as [x, y, z], stamps in seconds, not-a-number as null."""
    if isinstance(value, PoseStamped):
        return plain(pose_list(value.pose))
    if isinstance(value, Vector3):
        return plain([value.x, value.y, value.z])
    if isinstance(value, genpy.Message):
        return {name: plain(getattr(value, name)) for name in value.__slots__}
    if isinstance(value, (genpy.Time, genpy.Duration)):
        return value.to_sec()
    if isinstance(value, (list, tuple)):
        return [plain(v) for v in value]
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def response_json(res):
    """Every field of the ranking's response; the scene's frame and stamp, and the poses' frame."""
    out = {"frame": res.header.frame_id, "scene_stamp": res.header.stamp.to_sec(),
           "pose_frame": res.grasps[0].tool_pose.header.frame_id if res.grasps else ""}
    out.update((name, plain(getattr(res, name))) for name in res.__slots__ if name != "header")
    return out


def progress(done, total, best):
    """Feedback of the ranking action, one line per tenth of the pulls."""
    if done == total or done % max(1, total // 10) == 0:
        sys.stderr.write("pulls %d of %d%s\n" % (
            done, total, "" if best is None else "; best so far: %s, freed %.0f %%" % (
                "held" if best.held else "failed", 100 * best.freed_share)))


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0].replace("\n", " "),
                                     formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    which = parser.add_mutually_exclusive_group(required=True)
    which.add_argument("--target", help="object id, or 'top' for the highest")
    which.add_argument("--point", help="X,Y,Z (metres, in --point-frame): the object whose surface "
                                       "is nearest this point")
    parser.add_argument("--point-frame", default="",
                        help="tf frame of --point (required with it), e.g. base_link")
    parser.add_argument("--candidates", type=int, default=0, help="grasps to simulate (0: the node's)")
    parser.add_argument("--pull-distance", type=float, default=0.10, help="metres")
    parser.add_argument("--pull-speed", type=float, default=0.20, help="metres per second")
    parser.add_argument("--hypotheses", type=int, default=0,
                        help="scene hypotheses (1: objects alone; 0: all the scene carries)")
    parser.add_argument("--camera", default="camera", help="namespace of the perception and grasp nodes")
    parser.add_argument("--rows", type=int, default=10, help="grasps printed")
    parser.add_argument("--timeout", type=float, default=30.0,
                        help="seconds to wait for each of the master, the scene and the grasp "
                             "server (not for the ranking)")
    parser.add_argument("--result-timeout", type=float, default=None,
                        help="seconds the ranking may take before it is cancelled (none: no bound)")
    parser.add_argument("--max-age", type=float, default=None,
                        help="with --target top: refuse a scene older than this (s; 0: any age; "
                             "default: the server's ~max_scene_age_s, which it applies to "
                             "requests that carry no scene)")
    parser.add_argument("--frame", default="",
                        help="tf frame of the printed and written poses (empty: the scene's)")
    parser.add_argument("--pregrasp", type=float, default=0.0,
                        help="pre-grasp stand-off in metres (0: the server's ~pregrasp_distance_m)")
    parser.add_argument("--progress", action="store_true",
                        help="print the pulls done as they are simulated (on stderr)")
    parser.add_argument("--json", help="also write the response to this file (every field; poses as "
                        "[x, y, z, qw, qx, qy, qz])")
    argv = rospy.myargv()[1:]
    # A point whose first coordinate is negative ("--point -0.2,0.1,0.05") would read as an
    # option: it is joined to its option first.
    for i in range(len(argv) - 2, -1, -1):
        if argv[i] == "--point" and argv[i + 1].startswith("-"):
            argv[i:i + 2] = ["--point=" + argv[i + 1]]
    args = parser.parse_args(argv)
    # The request's counts are uint32: one outside is an argument error, not a traceback.
    for name in ("candidates", "hypotheses", "rows"):
        if not 0 <= getattr(args, name) <= 2**32 - 1:
            parser.error("--%s must lie in [0, 4294967295], not %d" % (name, getattr(args, name)))
    # Checked here, before the master is waited for: a wrong number is said at once. The bounds
    # are the server's (its answer names them); finite and positive is what any request needs.
    if not (math.isfinite(args.timeout) and args.timeout > 0):
        parser.error("--timeout must be a finite number of seconds > 0")
    if args.result_timeout is not None and not (math.isfinite(args.result_timeout)
                                                and args.result_timeout > 0):
        parser.error("--result-timeout must be a finite number of seconds > 0")
    if args.max_age is not None and not (math.isfinite(args.max_age) and args.max_age >= 0):
        parser.error("--max-age must be a finite number of seconds >= 0")
    for name in ("pull_distance", "pull_speed"):
        if not (math.isfinite(getattr(args, name)) and getattr(args, name) > 0):
            parser.error("--%s must be a finite number > 0, not %s"
                         % (name.replace("_", "-"), getattr(args, name)))
    if not (math.isfinite(args.pregrasp) and args.pregrasp >= 0):
        parser.error("--pregrasp must be a finite number of metres >= 0, not %s" % args.pregrasp)
    if args.json:  # fail before the ranking, not after it
        if os.path.isdir(args.json):
            parser.error("--json %s is a directory: name a file" % args.json)
        folder = os.path.dirname(os.path.abspath(args.json))
        if not os.path.isdir(folder) or not os.access(folder, os.W_OK):
            parser.error("--json %s: %s is not a writable directory" % (args.json, folder))
    target = None
    point = None
    if args.point is not None:
        try:
            xyz = [float(v) for v in args.point.split(",")]
        except ValueError:
            xyz = []
        if len(xyz) != 3 or not all(math.isfinite(v) for v in xyz):
            parser.error("--point must be X,Y,Z (three finite numbers), not %r" % args.point)
        if not args.point_frame:
            parser.error("--point needs --point-frame (the tf frame it is given in)")
        point = PointStamped()
        point.header.frame_id = args.point_frame
        point.point.x, point.point.y, point.point.z = xyz
    elif args.point_frame:
        parser.error("--point-frame goes with --point")
    elif args.target != "top":
        try:
            target = int(args.target)
        except ValueError:
            target = -1
        if not 0 <= target <= 2**32 - 1:
            parser.error("--target must be an object id (0 to 4294967295) or 'top', not %r" % args.target)
    # rospy.init_node waits for a master without end: look for one first, up to --timeout.
    deadline = time.time() + args.timeout
    while not rosgraph.is_master_online():
        if time.time() > deadline:
            sys.exit("rank_grasps: no ROS master at %s within %g s" % (rosgraph.get_master_uri(), args.timeout))
        time.sleep(0.2)
    rospy.init_node("rank_grasps_client", anonymous=True)
    scene = None  # the server's latest
    try:
        if args.target == "top":
            scene = grasp_client.latest_scene(args.camera, args.timeout, args.max_age)
            target = grasp_client.top_object(scene)
        res = grasp_client.rank_grasps(scene, target, args.camera, args.candidates,
                                       args.pull_distance, args.pull_speed, args.hypotheses,
                                       args.timeout, args.frame, args.pregrasp, target_point=point,
                                       feedback=progress if args.progress else None,
                                       result_timeout=args.result_timeout)
    except grasp_client.GraspServiceError as e:
        if rospy.is_shutdown():  # Ctrl-C: the client has cancelled any ranking on the server
            print("rank_grasps: stopped (%s)" % e, file=sys.stderr)
            sys.exit(130)
        sys.exit("rank_grasps: %s%s" % ("" if e.status is None else e.status_name + ": ", e))
    print("object %d: %s (%d pulls in %d %s, %.2f s)" % (
        res.target_id, res.message, res.pulls, res.hypotheses_used,
        "scene" if res.hypotheses_used == 1 else "scenes",
        res.time_s))
    print(table(res, args.rows))
    if args.json:
        # Whole or not at all: written beside it, then renamed over it (a full disk leaves the
        # previous file, not half of this one).
        part = "%s.partial-%d" % (args.json, os.getpid())
        try:
            with open(part, "w") as f:
                json.dump(response_json(res), f, indent=1, allow_nan=False)
            os.replace(part, args.json)
        except OSError as e:
            if os.path.exists(part):
                os.remove(part)
            sys.exit("rank_grasps: --json %s not written: %s" % (args.json, e))
        print("wrote %s" % args.json)


if __name__ == "__main__":
    try:
        main()
    except KeyboardInterrupt:  # before the action exists: nothing to cancel
        sys.exit(130)
