#!/usr/bin/env python3
"""rostest node of test/ros/replay.test: the example bag replayed as a workcell would, with a
static base_link -> table transform and the perception's outputs in base_link (~output_frame):
the node is ready before the first frame and perceives every frame, ids stay with their objects,
late subscribers get the latched outputs, and grasps come as PoseStamped in base_link, their
target named by an id or by a point."""
import math
import multiprocessing
import threading
import time
import unittest

import actionlib
import rosbag
import rospkg
import rospy
import rostest
from actionlib_msgs.msg import GoalStatus
from geometry_msgs.msg import PointStamped
from simstack.msg import ObjectArray, RankGraspsAction, RankGraspsGoal
from simstack.srv import RankGrasps, RankGraspsRequest, SaveOctomap
from std_msgs.msg import Bool
from tf2_msgs.msg import TFMessage
from visualization_msgs.msg import MarkerArray

# base_link -> table (as replay.test publishes it): the table a quarter turn about z, raised.
BASE_FROM_TABLE = (0.6, -0.1, 0.75)
BASE_FROM_TABLE_ROTATION = (0.0, 0.0, math.sqrt(0.5), math.sqrt(0.5))


def quat_rotate(q, v):
    """v turned by the unit quaternion q (x, y, z, w)."""
    x, y, z, w = q
    t = (2 * (y * v[2] - z * v[1]), 2 * (z * v[0] - x * v[2]), 2 * (x * v[1] - y * v[0]))
    return (v[0] + w * t[0] + y * t[2] - z * t[1],
            v[1] + w * t[1] + z * t[0] - x * t[2],
            v[2] + w * t[2] + x * t[1] - y * t[0])


def quat_conjugate(q):
    return (-q[0], -q[1], -q[2], q[3])


def outward_normal(sq, p):
    """The superquadric's outward normal (gradient of its inside-outside function) at a point,
    both in the superquadric's frame."""
    o = sq.pose.orientation
    q = (o.x, o.y, o.z, o.w)
    c = sq.pose.position
    d = quat_rotate(quat_conjugate(q), (p[0] - c.x, p[1] - c.y, p[2] - c.z))
    a = (sq.semi_axes.x, sq.semi_axes.y, sq.semi_axes.z)
    e = (sq.exponents.x, sq.exponents.y, sq.exponents.z)
    g = [e[i] / a[i] * math.copysign(abs(d[i] / a[i]) ** (e[i] - 1.0), d[i]) for i in range(3)]
    return quat_rotate(q, g)


def server_up(client, timeout_s):
    """Whether the action server answered within timeout_s of wall time. The bag has played
    out and its clock stands still, so actionlib's own timeouts (ROS time) would never pass."""
    started = []
    waiter = threading.Thread(target=lambda: started.append(client.wait_for_server()), daemon=True)
    waiter.start()
    waiter.join(timeout_s)
    return bool(started and started[0])


def result_in(client, timeout_s):
    """Whether the goal ended within timeout_s of wall time (see server_up)."""
    deadline = time.time() + timeout_s
    while client.simple_state != actionlib.SimpleGoalState.DONE and time.time() < deadline:
        time.sleep(0.01)
    return client.simple_state == actionlib.SimpleGoalState.DONE


class Workcell(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        rospy.init_node("test_workcell")
        bag = rospkg.RosPack().get_path("simstack") + "/test/data/example_pile.bag"
        with rosbag.Bag(bag) as b:
            cls.bag_stamps = sorted(m.header.stamp.to_sec() for _, m, _ in
                                    b.read_messages(topics=["/camera/depth/image_rect"]))
        cls.scenes = {}
        cls.ready_before_first = None
        cls.object_frames = {}
        cls.tf_sub = rospy.Subscriber("/tf", TFMessage, cls.on_tf)
        cls.sub = rospy.Subscriber("/camera/perception/objects", ObjectArray, cls.on_scene)
        ready = rospy.wait_for_message("/camera/perception/ready", Bool, timeout=180)
        cls.ready = ready.data
        cls.ready_before_first = not cls.scenes
        deadline = time.time() + 240
        while len(cls.scenes) < len(cls.bag_stamps) and time.time() < deadline:
            time.sleep(0.2)
        rospy.wait_for_service("/camera/grasps/rank_grasps", timeout=60)
        cls.rank = rospy.ServiceProxy("/camera/grasps/rank_grasps", RankGrasps)

    @classmethod
    def on_tf(cls, msg):
        for t in msg.transforms:
            if t.child_frame_id.startswith("simstack_object_"):
                cls.object_frames[(round(t.header.stamp.to_sec(), 3), t.child_frame_id)] = t

    @classmethod
    def on_scene(cls, msg):
        cls.scenes[round(msg.header.stamp.to_sec(), 3)] = msg

    def last_scene(self):
        return self.scenes[max(self.scenes)]

    def test_1_ready_before_the_first_frame_and_every_frame_perceived(self):
        self.assertTrue(self.ready)
        self.assertTrue(self.ready_before_first)
        self.assertEqual(sorted(self.scenes), [round(s, 3) for s in self.bag_stamps])

    def test_2_ids_stay_with_their_objects(self):
        first = self.scenes[min(self.scenes)]
        self.assertGreater(len(first.objects), 0)
        compared = 0
        for stamp, scene in sorted(self.scenes.items()):
            for o in scene.objects:
                p = o.superquadric.pose.position
                near = min(first.objects, key=lambda f: math.dist(
                    (p.x, p.y, p.z), (f.superquadric.pose.position.x, f.superquadric.pose.position.y,
                                      f.superquadric.pose.position.z)))
                q = near.superquadric.pose.position
                if math.dist((p.x, p.y, p.z), (q.x, q.y, q.z)) < 0.02:
                    compared += 1
                    self.assertEqual(o.id, near.id, "frame %.2f: the object at (%.3f, %.3f, %.3f)" % (
                        stamp, p.x, p.y, p.z))
        # Most objects of most frames lie where one of the first frame's does: compared at all.
        self.assertGreaterEqual(compared, len(first.objects) * len(self.scenes) // 2)

    def test_3_late_subscribers_get_the_latched_outputs(self):
        markers = rospy.wait_for_message("/camera/perception/markers", MarkerArray, timeout=10)
        ids = sorted(m.id for m in markers.markers if m.ns == "superquadrics")
        self.assertEqual(ids, sorted(o.id for o in self.last_scene().objects))

    def test_4_grasps_in_base_link_point_into_the_target(self):
        scene = self.last_scene()
        top = max(scene.objects, key=lambda o: o.superquadric.pose.position.z)
        req = RankGraspsRequest(target_id=top.id, candidates=16, pull_distance_m=0.1,
                                pull_speed_mps=0.2, target_frame="base_link",
                                pregrasp_distance_m=0.07)
        res = self.rank(req)
        self.assertTrue(res.success, res.message)
        self.assertEqual(res.target_id, top.id)
        self.assertGreater(len(res.grasps), 0)
        for g in res.grasps:
            self.assertEqual(g.tool_pose.header.frame_id, "base_link")
            self.assertEqual(g.pregrasp_pose.header.frame_id, "base_link")
            t, o = g.tool_pose.pose.position, g.tool_pose.pose.orientation
            z = quat_rotate((o.x, o.y, o.z, o.w), (0.0, 0.0, 1.0))
            n = outward_normal(top.superquadric, (t.x, t.y, t.z))  # both in base_link
            self.assertLess(sum(a * b for a, b in zip(n, z)), 0.0, "z must point into the target")
            p = g.pregrasp_pose.pose.position
            self.assertAlmostEqual(math.dist((p.x, p.y, p.z), (t.x, t.y, t.z)), 0.07, 5)
            back = tuple(a - b for a, b in zip((p.x, p.y, p.z), (t.x, t.y, t.z)))
            self.assertAlmostEqual(sum(a * b for a, b in zip(back, z)), -0.07, 5)

    def test_5_a_target_named_by_a_point(self):
        scene = self.last_scene()
        for o in scene.objects:
            c = o.superquadric.pose.position
            point = PointStamped()
            point.header.frame_id = "base_link"
            point.point.x, point.point.y, point.point.z = c.x, c.y, c.z
            res = self.rank(RankGraspsRequest(target_id=999, target_point=point, candidates=4,
                                              pull_distance_m=0.1, pull_speed_mps=0.2))
            self.assertTrue(res.success, res.message)
            self.assertEqual(res.target_id, o.id)

    def test_7_each_object_is_a_tf_frame(self):
        for stamp, scene in self.scenes.items():
            for o in scene.objects:
                t = self.object_frames.get((stamp, "simstack_object_%d" % o.id))
                self.assertIsNotNone(t, "no tf frame simstack_object_%d at %.2f" % (o.id, stamp))
                self.assertEqual(t.header.frame_id, "base_link")
                p = o.superquadric.pose.position
                v = t.transform.translation
                self.assertAlmostEqual(math.dist((p.x, p.y, p.z), (v.x, v.y, v.z)), 0.0, 6)

    def test_9_outputs_are_in_the_output_frame(self):
        scene = self.last_scene()
        self.assertEqual(scene.header.frame_id, "base_link")
        p, o = scene.table_in_frame.position, scene.table_in_frame.orientation
        for a, b in zip((p.x, p.y, p.z, o.x, o.y, o.z, o.w), BASE_FROM_TABLE + BASE_FROM_TABLE_ROTATION):
            self.assertAlmostEqual(a, b, 5)
        # Every object stands on the table: its centre above the table's plane in base_link.
        for obj in scene.objects:
            c = obj.superquadric.pose.position
            self.assertGreater(c.z, BASE_FROM_TABLE[2])
        markers = rospy.wait_for_message("/camera/perception/markers", MarkerArray, timeout=10)
        self.assertTrue(all(m.header.frame_id == "base_link" for m in markers.markers))
        # The saved occupancy's coordinates are the table frame's grid, whatever the outputs'
        # frame: the answer names the table, not base_link.
        rospy.wait_for_service("/camera/perception/save_octomap", timeout=10)
        save = rospy.ServiceProxy("/camera/perception/save_octomap", SaveOctomap)
        res = save(file_name="workcell.bt")
        self.assertTrue(res.success, res.message)
        self.assertEqual(res.header.frame_id, "table")
        self.assertIn("'table'", res.message)

    def test_8_the_action_gives_feedback_and_a_cancel_stops_it(self):
        scene = self.last_scene()
        top = max(scene.objects, key=lambda o: o.superquadric.pose.position.z)
        client = actionlib.SimpleActionClient("/camera/grasps/rank_grasps_action", RankGraspsAction)
        self.assertTrue(server_up(client, 30), "no rank_grasps_action server")
        # A whole ranking: feedback after every pull, the result as the service's.
        feedback = []
        goal = RankGraspsGoal(target_id=top.id, candidates=8, pull_distance_m=0.1,
                              pull_speed_mps=0.2, target_frame="base_link")
        client.send_goal(goal, feedback_cb=feedback.append)
        self.assertTrue(result_in(client, 60), "no result within 60 s")
        result = client.get_result()
        self.assertEqual(client.get_state(), GoalStatus.SUCCEEDED, result.message)
        self.assertTrue(result.success)
        self.assertGreater(len(result.grasps), 0)
        self.assertEqual(result.grasps[0].tool_pose.header.frame_id, "base_link")
        # Feedback and result come on topics of their own, in no order between them: the last
        # pull's feedback may arrive just after the result.
        deadline = time.time() + 5
        while (not feedback or feedback[-1].pulls_done < result.pulls) and time.time() < deadline:
            time.sleep(0.01)
        done = [f.pulls_done for f in feedback]
        self.assertEqual(done, sorted(done))
        self.assertEqual(done[-1], result.pulls)
        self.assertTrue(feedback[-1].has_best)
        # A long ranking (slow, long pulls: minutes in all) cancelled after its first pulls: it
        # stops within a pull per thread (the server's threads are at most the cores; one more
        # pull's feedback may be on its way at the cancel), as test_grasping's
        # ProgressCountsEveryPullAndAStopEndsTheRankingWithinOnePullPerThread does in the core.
        feedback = []
        goal.candidates = 256
        goal.pull_distance_m, goal.pull_speed_mps = 0.5, 0.01
        client.send_goal(goal, feedback_cb=feedback.append)
        deadline = time.time() + 30
        while len(feedback) < 3 and time.time() < deadline:
            time.sleep(0.005)
        self.assertGreaterEqual(len(feedback), 3)
        done_at_cancel = feedback[-1].pulls_done
        client.cancel_goal()
        self.assertTrue(result_in(client, 30), "the cancelled ranking did not end")
        result = client.get_result()
        self.assertEqual(client.get_state(), GoalStatus.PREEMPTED, result.message)
        self.assertFalse(result.success)
        self.assertEqual(result.status, result.CANCELLED)
        self.assertIn("stopped after", result.message)
        self.assertLess(result.pulls, feedback[-1].pulls_total)
        self.assertLessEqual(result.pulls, done_at_cancel + multiprocessing.cpu_count() + 1,
                             "%d pulls done at the cancel" % done_at_cancel)
        # A cancel while two service requests wait for that ranking (holding the service's
        # threads) still stops it.
        feedback = []
        client.send_goal(goal, feedback_cb=feedback.append)
        deadline = time.time() + 30
        while len(feedback) < 3 and time.time() < deadline:
            time.sleep(0.005)
        answers = []
        request = RankGraspsRequest(target_id=top.id, candidates=4, pull_distance_m=0.1,
                                    pull_speed_mps=0.2)
        waiting = [threading.Thread(target=lambda: answers.append(self.rank(request)))
                   for _ in range(2)]
        for t in waiting:
            t.start()
        time.sleep(1.0)  # both requests in the server, waiting
        client.cancel_goal()
        self.assertTrue(result_in(client, 60), "the cancel beside waiting requests did not end it")
        result = client.get_result()
        self.assertEqual(client.get_state(), GoalStatus.PREEMPTED, result.message)
        self.assertLess(result.pulls, feedback[-1].pulls_total)
        for t in waiting:
            t.join(120)
        self.assertEqual([a.success for a in answers], [True, True], [a.message for a in answers])

    def test_6_an_unknown_frame_is_refused_by_name(self):
        scene = self.last_scene()
        res = self.rank(RankGraspsRequest(target_id=scene.objects[0].id, target_frame="no_such_frame",
                                          candidates=4, pull_distance_m=0.1, pull_speed_mps=0.2))
        self.assertFalse(res.success)
        self.assertIn("no_such_frame", res.message)
        far = PointStamped()
        far.header.frame_id = "table"
        far.point.z = 3.0
        res = self.rank(RankGraspsRequest(target_point=far, candidates=4, pull_distance_m=0.1,
                                          pull_speed_mps=0.2))
        self.assertFalse(res.success)
        self.assertIn("target_point", res.message)


if __name__ == "__main__":
    rostest.rosrun("simstack", "workcell", Workcell)
