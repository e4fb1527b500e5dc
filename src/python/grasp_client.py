"""The task code's side of the simstack grasp service (docs/reference.md, "Grasp service"):
read the latest scene, choose a target in it, rank grasps on that target and keep those whose
pull held.

    import rospy
    from simstack import grasp_client

    rospy.init_node("pick_task")
    scene = grasp_client.latest_scene()              # refuses a stale or empty one
    target = grasp_client.top_object(scene)          # or any id of scene.objects
    res = grasp_client.rank_grasps(scene, target, target_frame="base_link")
    held = grasp_client.held_grasps(res)             # best first; empty: no pull held
    if held:
        tool = held[0].tool_pose                     # PoseStamped in base_link, z into the surface
        pregrasp = held[0].pregrasp_pose             # 5 cm back along the approach

Object ids stay with their objects from frame to frame, so an id chosen from one scene names
the same object in the next while it stays where it was.
"""
import threading
import time

import actionlib
import rospy
from simstack.msg import ObjectArray, RankGraspsAction, RankGraspsGoal


class GraspServiceError(RuntimeError):
    """The scene or the ranking could not be had; the message says why."""


def scene_age(scene):
    """Seconds since the scene's stamp, or None when there is nothing to judge it by (a stamp of
    0, or a simulated clock that has not ticked within 3 s: a bag that has ended)."""
    if scene.header.stamp.is_zero():
        return None
    deadline = time.time() + 3.0  # the first /clock message under simulated time
    now = rospy.Time.now()
    while now.is_zero() and time.time() < deadline:
        time.sleep(0.05)
        now = rospy.Time.now()
    return None if now.is_zero() else (now - scene.header.stamp).to_sec()


def latest_scene(camera="camera", timeout=10.0, max_age=None):
    """The latest ObjectArray on /<camera>/perception/objects. It is latched, so it comes at once
    however old it is: refused when its stamp is more than `max_age` seconds behind the clock
    (None: the grasp server's ~max_scene_age_s, 10 s when unset; 0: any age), or when it holds
    no object."""
    topic = "/%s/perception/objects" % camera
    try:
        scene = rospy.wait_for_message(topic, ObjectArray, timeout=timeout)
    except rospy.ROSException as e:
        raise GraspServiceError("no scene on %s: %s" % (topic, e))
    if max_age is None:
        max_age = float(rospy.get_param("/%s/grasps/max_scene_age_s" % camera, 10.0))
    age = scene_age(scene)
    if max_age > 0 and age is not None and age > max_age:
        raise GraspServiceError("the latest scene on %s is %.1f s old (max age %g s): %s" % (
            topic, age, max_age,
            "a day or more apart: is one of this client and the perception on simulated time "
            "(/use_sim_time) and the other not?" if age > 86400 else
            "is the perception still running?"))
    if not scene.objects:
        raise GraspServiceError("the latest scene on %s has no objects" % topic)
    return scene


def top_object(scene):
    """The id of the object whose centre is highest: on a pile, one nothing rests on."""
    if not scene.objects:
        raise GraspServiceError("the scene has no objects")
    return max(scene.objects, key=lambda o: o.superquadric.pose.position.z).id


def rank_grasps(scene, target_id, camera="camera", candidates=0, pull_distance_m=0.10,
                pull_speed_mps=0.20, hypotheses=0, timeout=30.0, target_frame="",
                pregrasp_distance_m=0.0, target_point=None, feedback=None):
    """Ranks grasps through the action /<camera>/grasps/rank_grasps_action on `target_id` of
    `scene` (an ObjectArray; None: the server's latest, which it refuses when older than its
    ~max_scene_age_s) and returns the result (the fields of the service's response). `timeout`
    bounds the wait for the server, not the ranking: a request simulates candidates x
    hypotheses pulls (64 x 3 by default: about 0.5 s on a 4-object pile, docs/benchmarks.md;
    slower or longer pulls take longer in proportion). `feedback(done, total, best)` is called
    after each pull (`best`: the best grasp whose every pull is done, or None). `target_frame`
    (any tf frame) is the frame of the grasps' tool and pre-grasp poses ("": the scene's);
    `target_point` (a geometry_msgs/PointStamped) names the target instead of `target_id`: the
    object whose surface is nearest it. Raises GraspServiceError with the server's message when
    it refuses the request; KeyboardInterrupt cancels the ranking on the server."""
    name = "/%s/grasps/rank_grasps_action" % camera
    goal = RankGraspsGoal(target_id=target_id, candidates=candidates,
                          pull_distance_m=pull_distance_m, pull_speed_mps=pull_speed_mps,
                          hypotheses=hypotheses, target_frame=target_frame,
                          pregrasp_distance_m=pregrasp_distance_m)
    if target_point is not None:
        goal.target_point = target_point
    if scene is not None:
        goal.scene = scene
    client = actionlib.SimpleActionClient(name, RankGraspsAction)
    # On the wall clock: actionlib's own timeout reads ROS time, which under a looping or
    # paused bag may never reach it.
    waiting = threading.Thread(target=client.wait_for_server, daemon=True)
    waiting.start()
    waiting.join(timeout)
    if waiting.is_alive():
        raise GraspServiceError("no grasp server at %s within %g s (is grasps.launch running?)" % (
            name, timeout))

    def on_feedback(f):
        if feedback is not None:
            feedback(f.pulls_done, f.pulls_total, f.best if f.has_best else None)

    client.send_goal(goal, feedback_cb=on_feedback)
    try:
        client.wait_for_result()
    except BaseException:
        client.cancel_goal()
        raise
    res = client.get_result()
    if res is None:
        raise GraspServiceError("%s: no result (the server stopped?)" % name)
    if not res.success:
        raise GraspServiceError(res.message)
    return res


def held_grasps(res):
    """The ranked grasps whose pull held in every hypothesis, best first. The response lists
    every candidate, also those whose seal broke (ranked last, held false); when none held,
    res.message says so."""
    return [g for g in res.grasps if g.held]
