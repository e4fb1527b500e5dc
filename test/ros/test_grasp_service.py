#!/usr/bin/env python3
"""rostest node of test/ros/grasps.test: the grasp service on the replayed example bag."""
import copy
import json
import math
import os
import signal
import subprocess
import tempfile
import threading
import time
import unittest

import actionlib
import rospkg
import rospy
import rostest
from actionlib_msgs.msg import GoalStatus
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from simstack.msg import (Grasp, ObjectArray, Object, RankGraspsAction, RankGraspsActionResult,
                          RankGraspsGoal, SceneSample)
from simstack.srv import RankGrasps, RankGraspsRequest, RankGraspsResponse
from visualization_msgs.msg import Marker, MarkerArray


def request(**fields):
    req = RankGraspsRequest(target_id=0, candidates=12, pull_distance_m=0.1, pull_speed_mps=0.2)
    for name, value in fields.items():
        setattr(req, name, value)
    return req


class GraspService(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        rospy.init_node("test_grasp_service")
        cls.scene = rospy.wait_for_message("/camera/perception/objects", ObjectArray, timeout=180)
        for name in ("grasps", "lonely_grasps", "strict_grasps"):
            rospy.wait_for_service("/camera/%s/rank_grasps" % name, timeout=60)
        cls.rank = rospy.ServiceProxy("/camera/grasps/rank_grasps", RankGrasps)
        cls.lonely = rospy.ServiceProxy("/camera/lonely_grasps/rank_grasps", RankGrasps)
        cls.strict = rospy.ServiceProxy("/camera/strict_grasps/rank_grasps", RankGrasps)

    def scene_with(self, change):
        scene = copy.deepcopy(self.scene)
        change(scene.objects[0].superquadric)
        return scene

    def test_1_latest_objects_give_ranked_grasps_and_markers(self):
        self.assertGreater(len(self.scene.objects), 0)
        markers = []
        sub = rospy.Subscriber("/camera/grasps/grasps", MarkerArray, markers.append)
        res = self.rank(request())
        self.assertTrue(res.success, res.message)
        self.assertGreater(len(res.grasps), 0, res.message)
        self.assertLessEqual(len(res.grasps), 12)
        self.assertEqual(res.hypotheses_used, 1)
        self.assertIn("carries no hypotheses", res.message)  # replay.launch: `fc`, one scene
        self.assertEqual(len(res.baseline_displacement_m), 1)
        self.assertEqual(len(res.settle_displacement_m), 1)
        self.assertEqual(res.pulls, len(res.grasps))
        for better, worse in zip(res.grasps, res.grasps[1:]):
            self.assertLessEqual(better.failed_share, worse.failed_share)
        for g in res.grasps:
            self.assertAlmostEqual(math.sqrt(g.approach.x ** 2 + g.approach.y ** 2 + g.approach.z ** 2), 1.0, 4)
        deadline = time.time() + 10.0  # wall clock: the looping bag's clock jumps back
        while not markers and time.time() < deadline:
            time.sleep(0.1)
        self.assertTrue(markers, "no ~grasps markers")
        arrows = [m for m in markers[-1].markers if m.ns == "grasps" and m.type == Marker.ARROW]
        self.assertEqual(len(arrows), len(res.grasps))
        # A refused request has no grasps: the arrows of the last ranking are taken off.
        shown = len(markers)
        self.assertFalse(self.rank(request(target_id=99)).success)
        deadline = time.time() + 10.0
        while len(markers) == shown and time.time() < deadline:
            time.sleep(0.1)
        sub.unregister()
        self.assertGreater(len(markers), shown, "no ~grasps markers after a refusal")
        self.assertEqual([m.action for m in markers[-1].markers], [Marker.DELETEALL])

    def expect_rejected(self, req, words, status, service=None):
        res = (service or self.rank)(req)
        self.assertFalse(res.success, "accepted: %s" % words)
        self.assertIn(words, res.message)
        self.assertEqual(res.status, status, "%s: %s" % (words, res.message))
        self.assertEqual(len(res.grasps), 0)

    def test_2_bad_requests_are_answered_and_the_service_keeps_serving(self):
        bad_request, bad_scene = RankGraspsResponse.BAD_REQUEST, RankGraspsResponse.BAD_SCENE
        self.expect_rejected(request(target_id=99), "unknown target id 99",
                             RankGraspsResponse.UNKNOWN_TARGET)
        self.expect_rejected(request(pull_distance_m=0.0), "pull_distance_m", bad_request)
        self.expect_rejected(request(pull_distance_m=-0.1), "pull_distance_m", bad_request)
        self.expect_rejected(request(pull_speed_mps=float("nan")), "pull_speed_mps", bad_request)
        self.expect_rejected(request(pull_distance_m=0.5, pull_speed_mps=0.005), "over 60 s",
                             bad_request)

        def nan_axis(sq):
            sq.semi_axes.x = float("nan")

        def zero_axis(sq):
            sq.semi_axes.y = 0.0

        def negative_axis(sq):
            sq.semi_axes.z = -0.05

        def low_exponent(sq):
            sq.exponents.x = 0.3

        def infinite_exponent(sq):
            sq.exponents.y = float("inf")

        def long_quaternion(sq):
            sq.pose.orientation.w *= 2.0

        def nan_position(sq):
            sq.pose.position.x = float("nan")

        for change, words in ((nan_axis, "semi-axes"), (zero_axis, "semi-axes"),
                              (negative_axis, "semi-axes"), (low_exponent, "exponents"),
                              (infinite_exponent, "exponents"), (long_quaternion, "quaternion"),
                              (nan_position, "not finite")):
            self.expect_rejected(request(scene=self.scene_with(change)), words, bad_scene)
        # A malformed scene is the scene's fault also when the target is chosen by a point.
        pointed = request(scene=self.scene_with(nan_axis))
        pointed.target_point.header.frame_id = self.scene.header.frame_id
        pointed.target_point.point.z = 0.05
        self.expect_rejected(pointed, "semi-axes", bad_scene)
        eye = request(use_camera_pose=True)
        eye.camera_pose.position.x = float("nan")
        self.expect_rejected(eye, "camera_pose.position is not finite", bad_request)
        unset = request(use_camera_pose=True)  # the pose left at zeros: on the table plane
        self.expect_rejected(unset, "m above the table plane, where no camera sees the pile",
                             bad_request)
        self.expect_rejected(request(), "no scene has arrived", RankGraspsResponse.NO_SCENE,
                             self.lonely)
        twice = copy.deepcopy(self.scene)
        self.assertGreater(len(twice.objects), 1)
        twice.objects[1].id = twice.objects[0].id
        self.expect_rejected(request(scene=twice), "appears twice", bad_scene)
        nowhere = copy.deepcopy(self.scene)
        nowhere.header.frame_id = ""
        self.expect_rejected(request(scene=nowhere), "frame_id", bad_scene)
        nowhere.header.frame_id = "/"  # tf2's name for no frame: poses in no frame either
        self.expect_rejected(request(scene=nowhere), "frame_id is '/'", bad_scene)
        frameless = request()
        frameless.target_point.point.x = 0.1
        self.expect_rejected(frameless, "target_point has no header.frame_id", bad_request)
        self.expect_rejected(request(target_frame="/"), "target_frame '/' names no frame",
                             bad_request)
        # One view's table pose, set but malformed: refused, not passed over (the test for
        # grasps into an opening the camera saw needs the camera).
        self.assertEqual(self.scene.views, 1)
        tilted = copy.deepcopy(self.scene)
        tilted.table_pose.orientation.x = float("nan")
        self.expect_rejected(request(scene=tilted), "table_pose", bad_scene)
        # A hand-built object whose surface cloud lacks the points measured_points announces.
        hollow = copy.deepcopy(self.scene)
        seen = max(hollow.objects, key=lambda o: o.measured_points)
        self.assertGreater(seen.measured_points, 0)
        seen.surface.point_step = 0
        seen.surface.data = b""
        self.expect_rejected(request(scene=hollow, target_id=seen.id), "point_step 0", bad_scene)
        res = self.rank(request())
        self.assertTrue(res.success, res.message)
        self.assertEqual(res.status, RankGraspsResponse.SUCCEEDED)
        self.assertGreater(len(res.grasps), 0)

    def test_2a_a_surface_cloud_not_on_its_target_is_set_aside_and_said(self):
        res = self.rank(request())
        self.assertTrue(res.success, res.message)
        self.assertNotIn("seals judged on the superquadric alone", res.message)
        # A hand-built scene whose target carries the cloud of the object furthest from it.
        scene = copy.deepcopy(self.scene)
        target = next(o for o in scene.objects if o.id == 0)
        self.assertGreater(target.measured_points, 0)

        def centre(o):
            p = o.superquadric.pose.position
            return (p.x, p.y, p.z)

        other = max((o for o in scene.objects if o.measured_points > 0 and o is not target),
                    key=lambda o: math.dist(centre(o), centre(target)))
        target.surface, target.measured_points = other.surface, other.measured_points
        res = self.rank(request(scene=scene))
        self.assertTrue(res.success, res.message)
        self.assertIn("seals judged on the superquadric alone: of the target's surface cloud, ",
                      res.message)
        self.assertIn("cm of its superquadric", res.message)

    def test_2b_a_scene_off_the_table_plane_is_said_or_refused(self):
        # The camera's orientation is not used (candidates are what is in sight of its
        # position), so an all-zero quaternion is no error.
        eye = request(scene=self.scene, use_camera_pose=True)
        eye.camera_pose.position.z = 1.0
        res = self.rank(eye)
        self.assertTrue(res.success, res.message)
        self.assertGreater(res.candidates_seen, 0)

        def moved(dz):
            scene = copy.deepcopy(self.scene)
            scene.header.frame_id = "base_link"
            for o in scene.objects:
                o.superquadric.pose.position.z += dz
            del scene.hypotheses[:]
            return scene

        raised = self.rank(request(scene=moved(0.7)))
        self.assertTrue(raised.success, raised.message)
        self.assertIn("lowest surface is at z = 0.", raised.message)
        self.assertIn("fall before any pull", raised.message)
        # It fell 0.7 m before the pulls: the answer says so, in the message and per scene.
        self.assertGreater(raised.settle_displacement_m[0], 0.6)
        self.assertIn("while settling before the pulls", raised.message)
        self.expect_rejected(request(scene=moved(-0.3)), "would stand in the table",
                             RankGraspsResponse.BAD_SCENE)
        self.assertNotIn("lowest surface", self.rank(request(scene=self.scene)).message)

    def test_3_too_many_candidates_are_clamped_and_said(self):
        res = self.lonely(request(scene=self.scene, candidates=1000))
        self.assertTrue(res.success, res.message)
        self.assertIn("1000 candidates asked for, clamped", res.message)
        self.assertLessEqual(len(res.grasps), 8)
        # The number asked is said as asked, however large.
        res = self.lonely(request(scene=self.scene, candidates=4294967295))
        self.assertIn("4294967295 candidates asked for", res.message)

    def test_4_a_target_without_sealable_surface_gives_no_grasps_and_says_why(self):
        scene = copy.deepcopy(self.scene)
        ball = scene.objects[0]
        ball.superquadric.semi_axes.x = ball.superquadric.semi_axes.y = 0.02
        ball.superquadric.semi_axes.z = 0.02
        ball.superquadric.exponents.x = ball.superquadric.exponents.y = 2.0
        ball.superquadric.exponents.z = 2.0
        ball.superquadric.pose.position.z = 0.02
        scene.objects = [ball]
        res = self.rank(request(scene=scene))
        self.assertTrue(res.success, res.message)
        self.assertEqual(len(res.grasps), 0)
        self.assertIn("no sealable surface", res.message)

    def test_5_hypotheses_default_to_all_the_scene_carries(self):
        scene = copy.deepcopy(self.scene)
        del scene.hypotheses[:]
        for dx in (0.004, -0.004):
            sample = SceneSample()
            for o in scene.objects:
                sq = copy.deepcopy(o.superquadric)
                sq.pose.position.x += dx
                sample.superquadrics.append(sq)
            scene.hypotheses.append(sample)
        res = self.rank(request(scene=scene, candidates=4))
        self.assertTrue(res.success, res.message)
        self.assertEqual(res.hypotheses_used, 3)
        self.assertNotIn("carries no hypotheses", res.message)
        self.assertEqual(len(res.baseline_displacement_m), 3)
        self.assertEqual(self.rank(request(scene=scene, candidates=4, hypotheses=1)).hypotheses_used, 1)
        more = self.rank(request(scene=scene, candidates=4, hypotheses=5))
        self.assertEqual(more.hypotheses_used, 3)
        self.assertIn("5 hypotheses asked for, the scene has 3", more.message)
        many = self.rank(request(scene=scene, candidates=4, hypotheses=1000))
        self.assertIn("1000 hypotheses asked for, the scene has 3", many.message)

    def test_6_a_stale_latest_scene_is_refused_and_a_fresh_one_ranked(self):
        # Simulated time from the looping bag: its clock restarts at 1 s every few seconds, so
        # waits here are on the wall clock (rospy.sleep raises when the clock jumps back).
        pub = rospy.Publisher("/camera/strict/objects", ObjectArray, queue_size=1, latch=True)
        deadline = time.time() + 10.0
        while pub.get_num_connections() == 0 and time.time() < deadline:
            time.sleep(0.05)
        self.assertGreater(pub.get_num_connections(), 0, "strict_grasps never subscribed")

        def rank_until(stamp_of, done):
            """Publishes the scene stamped stamp_of() and asks again until done(answer)."""
            answer = None
            deadline = time.time() + 20.0
            while time.time() < deadline:
                scene = copy.deepcopy(self.scene)
                scene.header.stamp = stamp_of()
                pub.publish(scene)
                time.sleep(0.1)
                answer = self.strict(request(candidates=4))
                if done(answer):
                    break
            return answer

        # The bag's clock never reads below 1 s, so a scene stamped near 0 is over 0.8 s old.
        stale = rank_until(lambda: rospy.Time(0, 1000), lambda a: "s old" in a.message)
        self.assertFalse(stale.success, "a stale scene was ranked")
        self.assertIn("s old (max_scene_age_s 0.8)", stale.message)
        self.assertEqual(stale.status, RankGraspsResponse.STALE_SCENE)
        fresh = rank_until(rospy.Time.now, lambda a: a.success)
        self.assertTrue(fresh.success, fresh.message)
        self.assertGreater(len(fresh.grasps), 0)
        # A scene brought by the request is ranked whatever its stamp.
        carried = copy.deepcopy(self.scene)
        carried.header.stamp = rospy.Time(0, 1000)
        self.assertTrue(self.strict(request(scene=carried, candidates=4)).success)

    def test_7_a_scene_that_comes_during_a_ranking_is_the_next_requests(self):
        # A request that waits for the ranking in progress ranks the newest scene, also one that
        # came while it waited (the server's scenes do not queue behind its service threads).
        busy = rospy.ServiceProxy("/camera/busy_grasps/rank_grasps", RankGrasps)
        rospy.wait_for_service("/camera/busy_grasps/rank_grasps", timeout=60)
        pub = rospy.Publisher("/camera/busy/objects", ObjectArray, queue_size=1, latch=True)
        deadline = time.time() + 10.0
        while pub.get_num_connections() == 0 and time.time() < deadline:
            time.sleep(0.05)
        self.assertGreater(pub.get_num_connections(), 0, "busy_grasps never subscribed")
        first = copy.deepcopy(self.scene)
        pub.publish(first)
        deadline = time.time() + 10.0
        while not busy(request(candidates=4)).success and time.time() < deadline:
            time.sleep(0.1)
        later = copy.deepcopy(self.scene)
        for o in later.objects:
            o.id += 1000
        answers = {}

        def ask(name, req):
            answers[name] = busy(req)

        # Slow pulls (50 s simulated each: several seconds in all), on a scene carried in the
        # goal, through the action: its first feedback says it has started, and the waiting
        # request comes after that.
        slow = actionlib.SimpleActionClient("/camera/busy_grasps/rank_grasps_action",
                                            RankGraspsAction)
        connect = threading.Thread(target=slow.wait_for_server, daemon=True)  # on the wall clock
        connect.start()
        connect.join(60)
        self.assertFalse(connect.is_alive(), "no action server on busy_grasps")
        started = threading.Event()
        slow.send_goal(RankGraspsGoal(scene=first, target_id=first.objects[0].id, candidates=256,
                                      pull_distance_m=0.5, pull_speed_mps=0.01),
                       feedback_cb=lambda f: started.set())
        self.assertTrue(started.wait(120), "the slow ranking gave no feedback")
        waiting = threading.Thread(target=ask, args=("waiting", request(
            target_id=later.objects[0].id, candidates=4)))
        waiting.start()
        time.sleep(0.5)
        pub.publish(later)
        time.sleep(1.0)
        still_ranking = slow.simple_state != actionlib.SimpleGoalState.DONE
        deadline = time.time() + 240
        while slow.simple_state != actionlib.SimpleGoalState.DONE and time.time() < deadline:
            time.sleep(0.05)
        waiting.join(240)
        answers["slow"] = slow.get_result()
        self.assertIsNotNone(answers["slow"], "the slow ranking gave no result")
        self.assertTrue(still_ranking, "the slow ranking ended before the new scene came (%.1f s)"
                        % answers["slow"].time_s)
        self.assertTrue(answers["slow"].success, answers["slow"].message)
        self.assertTrue(answers["waiting"].success, answers["waiting"].message)
        self.assertGreater(len(answers["waiting"].grasps), 0)

    def script(self, *args):
        """scripts/rank_grasps.py run as a user runs it: (exit code, stdout + stderr)."""
        path = os.path.join(rospkg.RosPack().get_path("simstack"), "scripts", "rank_grasps.py")
        done = subprocess.run([path] + list(args), capture_output=True, text=True, timeout=120)
        return done.returncode, done.stdout + done.stderr

    def test_8_the_script_ranks_the_top_object(self):
        folder = tempfile.TemporaryDirectory()
        self.addCleanup(folder.cleanup)
        path = os.path.join(folder.name, "grasps.json")
        code, out = self.script("--target", "top", "--candidates", "32", "--progress",
                                "--json", path)
        self.assertEqual(code, 0, out)
        self.assertRegex(out, r"object \d+: .*grasps ranked")
        self.assertIn("rank  contact (m, table)", out)
        # The action's feedback (the last may come after the result, which ends the goal).
        self.assertRegex(out, r"pulls \d+ of 32")
        # The file holds every field of the response and of each grasp, in strict JSON.
        with open(path) as f:
            written = json.load(f, parse_constant=lambda c: self.fail("%s in the JSON" % c))
        for field in RankGraspsResponse.__slots__:
            if field != "header":
                self.assertIn(field, written)
        self.assertGreater(written["scene_stamp"], 0)
        self.assertEqual(written["frame"], "table")
        self.assertGreater(len(written["grasps"]), 0)
        for field in Grasp.__slots__:
            self.assertIn(field, written["grasps"][0])
        self.assertEqual(len(written["grasps"][0]["tool_pose"]), 7)
        self.assertEqual(os.listdir(folder.name), ["grasps.json"])  # no partial file left
        # The target by a point in a tf frame; a namespace written with slashes works alike.
        code, out = self.script("--point", "-0.001,0,0.05", "--point-frame", "table",
                                "--candidates", "8", "--camera", "/camera/")
        self.assertEqual(code, 0, out)
        self.assertRegex(out, r"object \d+: .*grasps ranked")
        self.assertNotIn("not a legal ROS graph resource name", out)
        code, out = self.script("--point", "0,0,0.05")
        self.assertNotEqual(code, 0, out)
        self.assertIn("--point needs --point-frame", out)
        # A bad number is said at once, before the master is looked for (here none is there).
        for option, value in (("--pull-distance", "nan"), ("--timeout", "inf"),
                              ("--pregrasp", "-0.1")):
            path = os.path.join(rospkg.RosPack().get_path("simstack"), "scripts", "rank_grasps.py")
            done = subprocess.run([path, "--target", "top", option, value], capture_output=True,
                                  text=True, timeout=20,
                                  env=dict(os.environ, ROS_MASTER_URI="http://localhost:1"))
            self.assertEqual(done.returncode, 2, done.stdout + done.stderr)
            self.assertIn(option, done.stderr)

    def test_9_the_script_refuses_a_stale_latched_scene(self):
        # A latched scene arrives at once however old it is; the bag's clock reads 1 s or more.
        pub = rospy.Publisher("/stale/perception/objects", ObjectArray, queue_size=1, latch=True)
        stale = copy.deepcopy(self.scene)
        stale.header.stamp = rospy.Time(0, 1000)
        pub.publish(stale)
        # The default is the server's own limit, read from its parameter.
        rospy.set_param("/stale/grasps/max_scene_age_s", 0.5)
        code, out = self.script("--target", "top", "--camera", "stale", "--timeout", "30")
        self.assertNotEqual(code, 0, out)
        self.assertIn("s old (max age 0.5 s)", out)
        code, out = self.script("--target", "top", "--camera", "stale", "--max-age", "0",
                                "--timeout", "15")
        self.assertIn("/stale/grasps/rank_grasps", out)  # past the check, no server there


    def test_9b_task_code_imports_the_client_module(self):
        from simstack import grasp_client
        # Task code that forgot rospy.init_node is told so, not that nothing is there.
        forgot = subprocess.run(
            ["/usr/bin/python3", "-c", "from simstack import grasp_client as g\n"
             "try:\n g.latest_scene(timeout=1)\nexcept g.GraspServiceError as e:\n print(e)"],
            capture_output=True, text=True, timeout=60)
        self.assertIn("call rospy.init_node", forgot.stdout + forgot.stderr)
        scene = grasp_client.latest_scene(max_age=0)
        target = grasp_client.top_object(scene)
        self.assertIn(target, [o.id for o in scene.objects])
        res = grasp_client.rank_grasps(scene, target, candidates=8)
        self.assertTrue(res.success, res.message)
        # The service ranks as the action does: the same grasps of the same scene, in order.
        by_service = self.rank(request(scene=scene, target_id=target, candidates=8))
        self.assertTrue(by_service.success, by_service.message)
        self.assertEqual([(g.tool_pose.pose, g.freed_share, g.failed_share) for g in res.grasps],
                         [(g.tool_pose.pose, g.freed_share, g.failed_share)
                          for g in by_service.grasps])
        held = grasp_client.held_grasps(res)
        self.assertTrue(all(g.failed_share == 0.0 and g.held for g in held))
        self.assertEqual(held, [g for g in res.grasps if g.failed_share == 0.0])
        with self.assertRaisesRegex(grasp_client.GraspServiceError, "unknown target id 99") as e:
            grasp_client.rank_grasps(scene, 99)
        self.assertEqual(e.exception.status_name, "UNKNOWN_TARGET")
        with self.assertRaisesRegex(grasp_client.GraspServiceError, "no scene on /nowhere") as e:
            grasp_client.latest_scene("nowhere", timeout=1.0)
        self.assertEqual(e.exception.status, RankGraspsResponse.NO_SCENE)
        # A server that never comes: refused on time, and nothing left polling for it.
        threads = threading.active_count()
        with self.assertRaisesRegex(grasp_client.GraspServiceError,
                                    "no grasp server at /nowhere") as e:
            grasp_client.rank_grasps(scene, target, camera="nowhere", timeout=0.5)
        self.assertIsNone(e.exception.status)
        time.sleep(0.5)
        self.assertLessEqual(threading.active_count(), threads, threading.enumerate())

    def test_9c_the_client_checks_its_arguments_and_picks_the_top_above_the_table(self):
        from simstack import grasp_client
        scene = grasp_client.latest_scene(max_age=0)
        target = scene.objects[0].id
        for bad in (dict(target_id=-1), dict(target_id=None), dict(target_id=1.5),
                    dict(target_id=target, candidates=-2),
                    dict(target_id=target, pull_distance_m=float("nan")),
                    dict(target_id=target, result_timeout=float("inf")),
                    dict(target_id=target, timeout=0), dict(target_id=target, result_timeout=-1)):
            with self.assertRaises(grasp_client.GraspServiceError, msg=str(bad)):
                grasp_client.rank_grasps(scene, **bad)
        with self.assertRaisesRegex(grasp_client.GraspServiceError, "timeout must be above 0 s"):
            grasp_client.latest_scene(timeout=0)
        # A frame whose z is not up: the table turned a quarter about x, so that the table's
        # up is the frame's -y. Object 7 is higher in the frame's z, object 8 above the table.
        tilted = ObjectArray()
        tilted.header.frame_id = "camera_like"
        tilted.table_in_frame.orientation.w = math.sqrt(0.5)
        tilted.table_in_frame.orientation.x = math.sqrt(0.5)
        for oid, y, z in ((7, -0.05, 0.9), (8, -0.20, 0.5)):
            o = Object(id=oid)
            o.superquadric.pose.position.y = y
            o.superquadric.pose.position.z = z
            tilted.objects.append(o)
        self.assertEqual(grasp_client.top_object(tilted), 8)

    def test_9e_task_code_run_again_under_a_stopped_clock_is_ranked(self):
        # The same task run twice: the same node name, actionlib's goal count from the same
        # start, and the clock where it stood (a replayed bag that ended). actionlib's own goal
        # ids would repeat, and the server ignore the second goal.
        import actionlib.action_client as action_client
        from simstack import grasp_client
        scene = grasp_client.latest_scene(max_age=0)
        target = grasp_client.top_object(scene)
        count, frozen, now = action_client.g_goal_id, rospy.Time.now(), rospy.Time.__dict__["now"]
        rospy.Time.now = lambda: frozen
        try:
            for _ in range(2):
                action_client.g_goal_id = count
                res = grasp_client.rank_grasps(scene, target, candidates=4, result_timeout=60)
                self.assertTrue(res.success, res.message)
        finally:
            rospy.Time.now = now
        # A goal the server ignores (its id one the server lists already) ends in an error.
        fixed, unique = grasp_client._unique_goal_id(), grasp_client._unique_goal_id
        grasp_client._unique_goal_id = lambda: fixed
        try:
            grasp_client.rank_grasps(scene, target, candidates=4)
            with self.assertRaisesRegex(grasp_client.GraspServiceError,
                                        "the grasp server .* within 10 s"):
                grasp_client.rank_grasps(scene, target, candidates=4)
        finally:
            grasp_client._unique_goal_id = unique

    def action_results(self):
        """The grasp server's action results as they come (a list that grows)."""
        results = []
        sub = rospy.Subscriber("/camera/grasps/rank_grasps_action/result", RankGraspsActionResult,
                               results.append)
        self.addCleanup(sub.unregister)
        time.sleep(1.0)  # connected before the goal
        return results

    def wait_for_preempted(self, results):
        deadline = time.time() + 60
        while time.time() < deadline:
            if any(r.status.status == GoalStatus.PREEMPTED for r in results):
                return
            time.sleep(0.05)
        self.fail("no goal ended as cancelled: %s" % [r.status.status for r in results])

    def test_9f_diagnostics_count_the_answers_and_say_when_no_scene_came(self):
        statuses = {}

        def on_diagnostics(msg):
            for status in msg.status:
                statuses[status.name] = status

        sub = rospy.Subscriber("/diagnostics", DiagnosticArray, on_diagnostics)
        self.addCleanup(sub.unregister)
        names = ("camera/grasps: grasps", "camera/lonely_grasps: grasps")
        deadline = time.time() + 30
        while time.time() < deadline and not all(n in statuses for n in names):
            time.sleep(0.1)
        for name in names:
            self.assertIn(name, statuses, sorted(statuses))
        served = {kv.key: kv.value for kv in statuses[names[0]].values}
        self.assertGreater(int(served["requests answered"]), 0, served)
        self.assertGreater(int(served["answered SUCCEEDED"]), 0, served)
        self.assertGreater(int(served["answered BAD_REQUEST"]), 0, served)
        self.assertGreater(int(served["scenes received"]), 0, served)
        lonely = statuses[names[1]]
        self.assertEqual(lonely.level, DiagnosticStatus.OK, lonely.message)
        self.assertIn("no scene on", lonely.message)

    def test_9d_an_abandoned_ranking_is_cancelled_on_the_server(self):
        from simstack import grasp_client
        scene = grasp_client.latest_scene(max_age=0)
        target = grasp_client.top_object(scene)
        # A ranking long on any machine: 256 candidates pulled 30 s simulated each (about 7300
        # steps a pull); at the default 0.5 s pull they can all end within the 0.5 s bound below.
        slow = dict(candidates=256, pull_distance_m=0.3, pull_speed_mps=0.01)
        # A bound on the ranking's wall time.
        results = self.action_results()
        with self.assertRaisesRegex(grasp_client.GraspServiceError,
                                    "no result within 0.5 s; the ranking was cancelled"):
            grasp_client.rank_grasps(scene, target, result_timeout=0.5, **slow)
        self.wait_for_preempted(results)
        # Ctrl-C in the script (rospy's own SIGINT handler ends the wait).
        results = self.action_results()
        path = os.path.join(rospkg.RosPack().get_path("simstack"), "scripts", "rank_grasps.py")
        proc = subprocess.Popen([path, "--target", "top", "--max-age", "0", "--candidates",
                                 "256", "--pull-distance", "0.3", "--pull-speed", "0.01",
                                 "--progress"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                text=True)
        self.addCleanup(proc.kill)  # whatever fails below, no script left waiting
        # The first progress line (a tenth of the pulls done), with no error of actionlib's
        # before it (SimpleActionClient's "not tracking" race, which the client steps around).
        # Read by a thread of its own: a script that prints nothing fails the test in 120 s.
        lines = []

        def read_until_progress():
            while len(lines) < 20:
                lines.append(proc.stderr.readline())
                if not lines[-1] or "pulls" in lines[-1]:
                    return

        reader = threading.Thread(target=read_until_progress, daemon=True)
        reader.start()
        reader.join(120)
        self.assertFalse(reader.is_alive(), "no progress line in 120 s: " + "".join(lines))
        self.assertIn("pulls", lines[-1], "".join(lines))
        self.assertNotIn("not tracking", "".join(lines))
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=60)
        self.assertNotEqual(proc.returncode, 0, out + err)
        self.assertIn("cancelled on the server", err)
        self.wait_for_preempted(results)

if __name__ == "__main__":
    rostest.rosrun("simstack", "grasp_service", GraspService)
