#!/usr/bin/python3
"""Plays a bag into the perception once it is ready (launch/replay.launch): waits for the
latched `ready` topic of the perception node to say true, then runs `rosbag play` with the
remaining arguments, so that no frame of the bag reaches the node before it can perceive it.
Remappings after -- (camera/depth/image_rect:=camera/depth/image_rect_raw) go to rosbag play.

    play_when_ready.py --ready /camera/perception/ready [--timeout 300] -- --clock my.bag
"""
import argparse
import math
import os
import signal
import subprocess
import sys
import threading
import time

import rosbag
import rosgraph
import rospy
from std_msgs.msg import Bool


def main():
    argv = sys.argv[1:]
    split = argv.index("--") if "--" in argv else len(argv)
    # rosbag play's own, remappings included; roslaunch's __name:= and __log:= are this node's.
    play_args = [a for a in argv[split + 1:] if not a.startswith("__")]
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--ready", required=True, help="the perception's latched ready topic")
    parser.add_argument("--timeout", type=float, default=300.0,
                        help="seconds (wall clock) to wait for it before giving up (default: 300)")
    args = parser.parse_args(rospy.myargv(argv[:split]))
    if not play_args:
        parser.error("give the rosbag play arguments after --")
    if not (math.isfinite(args.timeout) and args.timeout > 0):
        parser.error("--timeout %s: give a number of seconds above 0" % args.timeout)
    # rosbag play reports a missing or broken bag and exits 0: refuse it here, before any wait.
    for bag in (a for a in play_args if a.endswith(".bag") and not a.startswith("-")):
        if not os.path.isfile(bag) or not os.access(bag, os.R_OK):
            sys.exit("play_when_ready: no readable bag file %s" % bag)
        try:
            rosbag.Bag(bag, "r", skip_index=True).close()  # its version line and header only
        except (rosbag.ROSBagException, OSError, ValueError) as e:
            sys.exit("play_when_ready: %s is not a bag rosbag can read: %s" % (bag, e))
    deadline = time.time() + args.timeout
    # rospy.init_node retries a missing master for ever: the deadline holds for it too.
    while not rosgraph.is_master_online():
        if time.time() > deadline:
            sys.exit("play_when_ready: no ROS master at %s within %g s (start roscore, or run "
                     "this from a launch file)" % (rosgraph.get_master_uri(), args.timeout))
        time.sleep(0.2)
    rospy.init_node("play_when_ready", anonymous=True, disable_signals=True)
    rospy.loginfo("play_when_ready: waiting for %s", args.ready)
    # One subscription and one deadline: a latched false (a perception that refused its model)
    # is waited past, not read again and again.
    said, ready = [], threading.Event()

    def on_ready(msg):
        said.append(msg.data)
        if msg.data:
            ready.set()

    sub = rospy.Subscriber(args.ready, Bool, on_ready)
    while not ready.wait(0.1):
        if time.time() > deadline or rospy.is_shutdown():
            sys.exit("play_when_ready: %s %s within %g s (did the perception start? its log says "
                     "why not)" % (args.ready, "said only false" if said else "said nothing",
                                   args.timeout))
    sub.unregister()
    rospy.loginfo("play_when_ready: %s is true, playing the bag", args.ready)
    player = subprocess.Popen(["rosbag", "play"] + play_args)
    # rosbag play leaves the master on SIGINT; on SIGTERM it dies registered, and the master
    # would go on naming a dead publisher of the bag's topics to every later subscriber. So
    # either signal here (roslaunch's SIGINT, a service manager's SIGTERM) is passed on as
    # SIGINT, and a player still running 10 s later is killed (roslaunch escalates after 15).
    asked = []

    def stop(*_):
        if not asked:
            asked.append(time.time())
        player.send_signal(signal.SIGINT)

    signal.signal(signal.SIGINT, stop)
    signal.signal(signal.SIGTERM, stop)
    while True:
        try:
            code = player.wait(timeout=0.5)
            break
        except subprocess.TimeoutExpired:
            if asked and time.time() - asked[0] > 10.0:
                player.kill()
    sys.exit(130 if code == -signal.SIGINT else code)


if __name__ == "__main__":
    try:
        main()
    except KeyboardInterrupt:  # stopped before the bag started
        sys.exit(130)
