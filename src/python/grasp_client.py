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
    best = next((g for g in held if g.freed), None)  # held and freed in every hypothesis
    if best:
        tool = best.tool_pose                        # PoseStamped in base_link, z into the surface
        pregrasp = best.pregrasp_pose                # 5 cm back along the approach

Object ids stay with their objects from frame to frame, so an id chosen from one scene names
the same object in the next while it stays where it was.
"""
import math
import threading
import time
import uuid

import actionlib
import rospy
from actionlib_msgs.msg import GoalID
from simstack.msg import ObjectArray, RankGraspsAction, RankGraspsGoal, RankGraspsResult

_STATUS_NAMES = {getattr(RankGraspsResult, n): n for n in (
    "SUCCEEDED", "NO_SCENE", "STALE_SCENE", "EMPTY_SCENE", "UNKNOWN_TARGET", "TF_UNAVAILABLE",
    "BAD_REQUEST", "BAD_SCENE", "CANCELLED", "INTERNAL_ERROR")}


class GraspServiceError(RuntimeError):
    """The scene or the ranking could not be had; the message says why, and `status` what task
    code can branch on: one of RankGraspsResult's constants (STALE_SCENE: perceive again;
    UNKNOWN_TARGET: choose another; TF_UNAVAILABLE, BAD_REQUEST, BAD_SCENE, ...), the server's
    when it answered and this client's own check's otherwise. None when no answer came: no
    server, no result in time, rospy shut down, or an exception of the feedback callback."""

    def __init__(self, message, status=None):
        RuntimeError.__init__(self, message)
        self.status = status

    @property
    def status_name(self):
        """The status's constant name ("STALE_SCENE"), or None."""
        return None if self.status is None else _STATUS_NAMES.get(self.status, str(self.status))


def _require_node():
    """rospy's topics and actions do nothing before rospy.init_node: say so, not that the
    server or the scene is missing."""
    if not rospy.core.is_initialized():
        raise GraspServiceError("call rospy.init_node(...) before using grasp_client")


def _clock_published():
    """Whether anything publishes /clock (a simulated clock that may yet tick)."""
    try:
        return any(name == "/clock" for name, _ in rospy.get_published_topics())
    except (OSError, rospy.ROSException) as e:
        raise GraspServiceError("cannot ask the ROS master what publishes /clock: %s" % e)


def scene_age(scene):
    """Seconds since the scene's stamp, or None when there is nothing to judge it by (a stamp of
    0, or a simulated clock that has not ticked: nothing publishes /clock, or it sent nothing
    within 3 s, as after a bag has ended)."""
    if scene.header.stamp.is_zero():
        return None
    now = rospy.Time.now()
    if now.is_zero() and _clock_published():
        deadline = time.time() + 3.0  # the first /clock message under simulated time
        while now.is_zero() and time.time() < deadline:
            time.sleep(0.05)
            now = rospy.Time.now()
    return None if now.is_zero() else (now - scene.header.stamp).to_sec()


def _namespace(camera):
    """`camera` as a namespace: without leading, trailing or doubled slashes ("/cell/kinect/"
    is cell/kinect); GraspServiceError when nothing is left."""
    parts = [p for p in str(camera).split("/") if p]
    if not parts:
        raise GraspServiceError("camera namespace %r names nothing" % (camera,),
                                RankGraspsResult.BAD_REQUEST)
    return "/".join(parts)


def _server_param(camera, name, default):
    """The grasp server's ~name (its default when unset); GraspServiceError without a master."""
    try:
        return rospy.get_param("/%s/grasps/%s" % (camera, name), default)
    except (OSError, rospy.ROSException) as e:
        raise GraspServiceError("cannot read /%s/grasps/%s from the ROS master: %s" % (
            camera, name, e))


def latest_scene(camera="camera", timeout=10.0, max_age=None, topic=None):
    """The latest ObjectArray on the topic the grasp server reads: its ~objects_topic under
    /<camera> (/<camera>/perception/objects by default; a remapping of the server's is not seen:
    give `topic` then). It is latched, so it comes at once however old it is: refused when its
    stamp is more than `max_age` seconds behind the clock (None: the grasp server's
    ~max_scene_age_s, 10 s when unset; 0: any age), or when it holds no object. `timeout`: None
    waits for ever."""
    _require_node()
    if timeout is not None:
        _check_seconds("timeout", timeout)
    camera = _namespace(camera)
    if topic is None:
        topic = _server_param(camera, "objects_topic", "perception/objects")
        topic = topic if topic.startswith("/") else "/%s/%s" % (camera, topic)
    try:
        scene = rospy.wait_for_message(topic, ObjectArray, timeout=timeout)
    except rospy.ROSException as e:
        raise GraspServiceError("no scene on %s: %s" % (topic, e), RankGraspsResult.NO_SCENE)
    if max_age is None:
        max_age = float(_server_param(camera, "max_scene_age_s", 10.0))
    age = scene_age(scene)
    if max_age > 0 and age is not None and age > max_age:
        raise GraspServiceError("the latest scene on %s is %.1f s old (max age %g s): %s" % (
            topic, age, max_age,
            "a day or more apart: is one of this client and the perception on simulated time "
            "(/use_sim_time) and the other not?" if age > 86400 else
            "is the perception still running?"), RankGraspsResult.STALE_SCENE)
    if not scene.objects:
        raise GraspServiceError("the latest scene on %s has no objects" % topic,
                                RankGraspsResult.EMPTY_SCENE)
    return scene


def _rotate(q, v):
    """v turned by the unit quaternion q (a geometry_msgs/Quaternion)."""
    u = (q.x, q.y, q.z)
    t = [2.0 * (u[1] * v[2] - u[2] * v[1]), 2.0 * (u[2] * v[0] - u[0] * v[2]),
         2.0 * (u[0] * v[1] - u[1] * v[0])]
    return [v[i] + q.w * t[i] + (u[(i + 1) % 3] * t[(i + 2) % 3] - u[(i + 2) % 3] * t[(i + 1) % 3])
            for i in range(3)]


def _height_above_table(scene, point):
    """The height (m) above the table of `point` (a geometry_msgs/Point in the scene's frame),
    through scene.table_in_frame (all zero, as in a message made by hand: the identity)."""
    t, q = scene.table_in_frame.position, scene.table_in_frame.orientation
    if (q.w, q.x, q.y, q.z) == (0.0, 0.0, 0.0, 0.0):
        return point.z - t.z
    inverse = type(q)(w=q.w, x=-q.x, y=-q.y, z=-q.z)
    return _rotate(inverse, [point.x - t.x, point.y - t.y, point.z - t.z])[2]


def top_object(scene):
    """The id of the object whose centre is highest above the table (whatever the scene's
    frame): on a pile, one nothing rests on."""
    if not scene.objects:
        raise GraspServiceError("the scene has no objects", RankGraspsResult.EMPTY_SCENE)
    return max(scene.objects,
               key=lambda o: _height_above_table(scene, o.superquadric.pose.position)).id


def _check_count(name, value):
    """A uint32 field of the goal: a whole number in [0, 2^32)."""
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value < 2 ** 32:
        raise GraspServiceError("%s must be a whole number from 0 to %d, not %r" % (
            name, 2 ** 32 - 1, value), RankGraspsResult.BAD_REQUEST)


def _check_number(name, value):
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise GraspServiceError("%s must be a finite number, not %r" % (name, value),
                                RankGraspsResult.BAD_REQUEST)


def _check_seconds(name, value):
    """A wait: a finite number of seconds above 0 (0 or less would give up at once)."""
    _check_number(name, value)
    if value <= 0:
        raise GraspServiceError("%s must be above 0 s, not %r" % (name, value),
                                RankGraspsResult.BAD_REQUEST)


# The goals in progress, cancelled on the server when rospy shuts down (its own Ctrl-C handler
# ends the wait before a KeyboardInterrupt could).
_active_lock = threading.Lock()
_active = set()
_hook_added = False


class _Goal(object):
    """One goal through actionlib's plain ActionClient, whose goal handle takes the server's
    statuses from the moment the goal is sent. (SimpleActionClient stores its handle only after
    sending, and logs an error when a local server's first status comes in between.)"""

    def __init__(self, client):
        self.client = client
        self.handle = None

    def send(self, goal, on_feedback):
        # A goal id of its own. actionlib's is the node's name, a count from 1 and the time:
        # task code run again under the same name while a replayed bag's clock stands still
        # sends an id the server already lists, and the server ignores that goal.
        self.client.manager._generate_id = _unique_goal_id
        self.handle = self.client.send_goal(goal, feedback_cb=lambda _, f: on_feedback(f))

    def state(self):
        return None if self.handle is None else self.handle.get_comm_state()

    def done(self):
        return self.handle is None or self.handle.get_comm_state() == actionlib.CommState.DONE

    def cancel(self):
        if self.handle is None:
            return
        # Under the goal's own lock, so that a result arriving meanwhile cannot be followed by a
        # cancel: a handle cancelled after its end would wait for an ack that never comes.
        with self.handle.comm_state_machine.mutex:
            if self.done():
                return
            try:
                self.handle.cancel()
            except rospy.ROSException:  # the client's topics already closed (rospy shutting down)
                pass

    def result(self):
        return None if self.handle is None else self.handle.get_result()


def _unique_goal_id():
    now = rospy.Time.now()
    return GoalID(id="%s-%s" % (rospy.get_caller_id(), uuid.uuid4().hex), stamp=now)


# How long (wall clock) the server may take to list a goal it received, which it does at once
# also while another ranking runs, and to send the result of a goal it lists as ended, which
# comes with the status. Either wait that outlasts this is a goal the server will not answer
# (one whose id it already listed), not a slow ranking.
_REPLY_TIMEOUT_S = 10.0
_NO_REPLY = {
    actionlib.CommState.WAITING_FOR_GOAL_ACK: "did not take the goal",
    actionlib.CommState.WAITING_FOR_RESULT: "ended the goal but sent no result",
}


def _cancel_and_wait(goal, seconds=2.0):
    """Cancels the goal and waits (wall clock) for the server to end it, so that the cancel has
    reached the server before the caller goes on or exits."""
    goal.cancel()
    deadline = time.time() + seconds
    while not goal.done() and time.time() < deadline:
        time.sleep(0.02)


def _cancel_active():
    with _active_lock:
        goals = list(_active)
    for goal in goals:
        _cancel_and_wait(goal)


def _track(goal):
    global _hook_added
    with _active_lock:
        if not _hook_added:
            rospy.on_shutdown(_cancel_active)  # run before rospy closes its topics
            _hook_added = True
        _active.add(goal)


def rank_grasps(scene, target_id, camera="camera", candidates=0, pull_distance_m=0.10,
                pull_speed_mps=0.20, hypotheses=0, timeout=30.0, target_frame="",
                pregrasp_distance_m=0.0, target_point=None, feedback=None, result_timeout=None):
    """Ranks grasps through the action /<camera>/grasps/rank_grasps_action on `target_id` of
    `scene` (an ObjectArray; None: the server's latest, which it refuses when older than its
    ~max_scene_age_s) and returns the result (the fields of the service's response). `timeout`
    bounds the wait for the server; `result_timeout` (seconds of wall time, None: no bound)
    the ranking itself, which is then cancelled: a request simulates candidates x hypotheses
    pulls (64 x 3 by default: about 0.5 s on a 4-object pile, docs/benchmarks.md; slower or
    longer pulls take longer in proportion). `feedback(done, total, best)` is called after each
    pull (`best`: the best grasp whose every pull is done, or None); an exception it raises
    cancels the ranking and is raised here. `target_frame` (any tf frame) is the frame of the
    grasps' tool and pre-grasp poses ("": the scene's); `target_point` (a
    geometry_msgs/PointStamped) names the target instead of `target_id` (which may then be
    None): the object whose surface is nearest it. Raises GraspServiceError with the server's
    message when it refuses the request, and when the server goes away, the ranking outlasts
    `result_timeout`, or rospy shuts down (Ctrl-C) before it ends; in the last two cases and on
    a KeyboardInterrupt the ranking is cancelled on the server first."""
    _require_node()
    if target_id is None and target_point is None:
        raise GraspServiceError("give a target_id, or a target_point", RankGraspsResult.BAD_REQUEST)
    _check_count("target_id", 0 if target_id is None else target_id)
    _check_count("candidates", candidates)
    _check_count("hypotheses", hypotheses)
    for name, value in (("pull_distance_m", pull_distance_m), ("pull_speed_mps", pull_speed_mps),
                        ("pregrasp_distance_m", pregrasp_distance_m)):
        _check_number(name, value)
    _check_seconds("timeout", timeout)
    if result_timeout is not None:
        _check_seconds("result_timeout", result_timeout)
    name = "/%s/grasps/rank_grasps_action" % _namespace(camera)
    goal = RankGraspsGoal(target_id=0 if target_id is None else target_id, candidates=candidates,
                          pull_distance_m=pull_distance_m, pull_speed_mps=pull_speed_mps,
                          hypotheses=hypotheses, target_frame=target_frame,
                          pregrasp_distance_m=pregrasp_distance_m)
    if target_point is not None:
        goal.target_point = target_point
    if scene is not None:
        goal.scene = scene
    sent = _Goal(actionlib.ActionClient(name, RankGraspsAction))
    try:
        return _run_goal(sent, name, goal, timeout, result_timeout, feedback)
    finally:
        with _active_lock:
            _active.discard(sent)
        sent.client.stop()  # its topics' callbacks would otherwise stay for good


def _server_ready(client):
    """Whether an action server is connected both ways: the test of actionlib's
    wait_for_server. The server is the node that sent the last status; the client's goal and
    cancel topics reach it, and its result and feedback topics reach the client."""
    status = client.last_status_msg
    if not status:
        return False
    server = status._connection_header["callerid"]
    if not (client.pub_goal.impl.has_connection(server) and
            client.pub_cancel.impl.has_connection(server)):
        return False
    return all(any(c.callerid_pub == server for c in sub.impl.connections)
               for sub in (client.result_sub, client.feedback_sub))


def _run_goal(sent, name, goal, timeout, result_timeout, feedback):
    # On the wall clock: actionlib's wait_for_server reads ROS time, which under a looping or
    # paused bag may never reach its timeout, and a thread left in it would poll until shutdown.
    deadline = time.time() + timeout
    while not _server_ready(sent.client):
        if rospy.is_shutdown():
            raise GraspServiceError("%s: rospy shut down (Ctrl-C?) before the server came" % name)
        if time.time() >= deadline:
            raise GraspServiceError("no grasp server at %s within %g s (is grasps.launch "
                                    "running?)" % (name, timeout))
        time.sleep(0.01)
    failures = []

    def on_feedback(f):
        if feedback is None or failures:
            return
        try:
            feedback(f.pulls_done, f.pulls_total, f.best if f.has_best else None)
        except BaseException as e:  # rospy would only log it
            failures.append(e)

    _track(sent)
    sent.send(goal, on_feedback)
    start = time.time()
    gone_since = None
    state, state_since = None, start
    try:
        while not sent.done():
            if failures:
                raise failures[0]
            if rospy.is_shutdown():
                raise GraspServiceError("%s: rospy shut down (Ctrl-C?) before the ranking ended; "
                                        "it was cancelled on the server" % name)
            if result_timeout is not None and time.time() - start > result_timeout:
                raise GraspServiceError("%s: no result within %g s; the ranking was cancelled" % (
                    name, result_timeout))
            if sent.state() != state:
                state, state_since = sent.state(), time.time()
            if state in _NO_REPLY and time.time() - state_since > _REPLY_TIMEOUT_S:
                raise GraspServiceError("%s: the grasp server %s within %g s" % (
                    name, _NO_REPLY[state], _REPLY_TIMEOUT_S))
            if sent.client.pub_goal.get_num_connections() == 0:
                gone_since = gone_since or time.time()
                if time.time() - gone_since > 2.0:
                    raise GraspServiceError("%s: the grasp server went away during the ranking" %
                                            name)
            else:
                gone_since = None
            time.sleep(0.02)
    except BaseException:
        if not rospy.is_shutdown():
            _cancel_and_wait(sent)
        raise
    if failures:
        raise failures[0]
    res = sent.result()
    if rospy.core.is_shutdown_requested():  # cancelled by _cancel_active
        raise GraspServiceError("%s: rospy shut down (Ctrl-C?) before the ranking ended; it was "
                                "cancelled on the server%s" % (
                                    name, "" if res is None else ": " + res.message))
    if res is None:
        raise GraspServiceError("%s: no result (the server stopped?)" % name)
    if not res.success:
        raise GraspServiceError(res.message, res.status)
    return res


def held_grasps(res):
    """The ranked grasps whose pull held in every hypothesis, best first. The response lists
    every candidate, also those whose seal broke (ranked last, held false); when none held,
    res.message says so."""
    return [g for g in res.grasps if g.held]
