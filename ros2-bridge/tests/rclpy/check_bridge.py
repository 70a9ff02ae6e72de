#!/usr/bin/env python3
"""armctl-ros2 on sim-host, driven by real rclpy (Jazzy or Kilted from the PyPI wheels).

Run by ros2-bridge/tests/rclpy.sh inside a private network namespace (DDS multicasts):
never run it on a shared network. Starts sim-host and the bridge as processes, then checks:

- graph and types: the bridge's node, topics, services and actions with the right types;
  every endpoint of the bridge carries a type hash (RIHS01) equal to rclpy's own for the
  same type; /clock, if there, is rosgraph_msgs/msg/Clock;
- /joint_states: the rate (by the median interval of the bridge's stamps; printed, bounded
  loosely: dds.rs checks the period exactly), none lost (DDS sequence numbers), the config's
  joint names, positions in radians;
- e-stop: 20 fresh clients (a new node and client each), each calling the Trigger service
  once: every first call answered, within 5 s (the latency is printed: p50, p90, max);
- a FollowJointTrajectory goal with velocities (MoveIt-style) ends SUCCEEDED exactly at the
  goal steps, with feedback at the configured rate, none lost; feedback is counted on the
  action's feedback topic (FeedbackTap), also for a client whose feedback callback lags;
- cancel mid-way: CANCELED, and the positions stamped after the result stop changing;
- wrong joint names: ABORTED, INVALID_JOINTS;
- gripper: a goal in range SUCCEEDS with feedback; one out of range is rejected;
- speed scaling and hold/resume (issue 32): 0.5 on the input, state 50 %, a 1 s goal takes
  at least 1.9 s; a goal held (state 0 %, joint_states still), resumed, ends exactly.

Prints one line per check and the figures, then 'N passed, N failed'. Exit status 1 if any
check failed. Every wait polls for what it waits for, with a deadline. No check asserts a
latency or a rate that a machine ten times slower or busier would miss: latencies are
printed (p50, p90, max), with each JointState's path (bridge, DDS, this client), and
bounded far above them.
"""

import argparse
import json
import math
import os
import statistics
import subprocess
import sys
import tempfile
import threading
import time

import rclpy
from rclpy.action import ActionClient, get_action_names_and_types
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.executors import MultiThreadedExecutor, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import QoSProfile

from action_msgs.msg import GoalStatus
from builtin_interfaces.msg import Duration
from control_msgs.action import FollowJointTrajectory, GripperCommand
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64
from std_srvs.srv import Trigger
from trajectory_msgs.msg import JointTrajectoryPoint

RESULTS = []

# Checks of work not done yet, by name prefix (ARMCTL_RCLPY_KNOWN, comma-separated): their
# failures print KNOWN and do not fail the run. Empty (rclpy.sh's default): every check counts.
KNOWN = [k.strip() for k in os.environ.get("ARMCTL_RCLPY_KNOWN", "").split(",") if k.strip()]


def check(name, ok, detail=""):
    known = not ok and any(name.startswith(k) for k in KNOWN)
    RESULTS.append((name, bool(ok) or known))
    mark = "ok  " if ok else ("KNOWN" if known else "FAIL")
    print(f"{mark} {name}{': ' + detail if detail else ''}", flush=True)
    return ok


def figure(text):
    print(f"FIGURE {text}", flush=True)


def wait_until(condition, timeout, step=0.01):
    """Polls `condition` until it is true or `timeout` seconds pass; its last value."""
    deadline = time.monotonic() + timeout
    while True:
        value = condition()
        if value or time.monotonic() >= deadline:
            return value
        time.sleep(step)


def wait_future(future, timeout):
    done = threading.Event()
    future.add_done_callback(lambda _: done.set())
    if not done.wait(timeout):
        return None
    return future.result()


def stamp_seconds(stamp):
    return stamp.sec + stamp.nanosec * 1e-9


def quantiles_ms(values):
    """'p50 X ms, p90 Y ms, max Z ms' of `values` in seconds."""
    ms = sorted(v * 1000 for v in values)
    if not ms:
        return "no values"
    at = lambda q: ms[min(len(ms) - 1, int(q * len(ms)))]
    return f"p50 {at(0.5):.1f} ms, p90 {at(0.9):.1f} ms, max {ms[-1]:.1f} ms"


def duration(seconds):
    sec = math.floor(seconds)
    return Duration(sec=int(sec), nanosec=int(round((seconds - sec) * 1e9)))


class FeedbackTap:
    """Every feedback message published on one action's feedback topic, with its DDS
    publication sequence number: a plain subscription beside the ActionClient.

    The feedback checks count here, not in the ActionClient's feedback callback: rclpy's
    ActionClient forgets a goal's feedback callback once the goal's result is in, and drops
    whatever feedback it takes after that. A client whose callbacks run behind the DDS
    reception (this one on a busy 2-core machine: up to 1 s, a Kilted .ci/run of 2026-11-29)
    so lost 23 of a goal's 60 messages (it took them over 2.07 s; their stamps covered
    1.2 s of the 2 s goal without a gap), and the check charged that to the bridge.
    """

    # 33 s of feedback at 30 Hz: a client that far behind still loses nothing here.
    DEPTH = 1000

    def __init__(self, node, action_type, action_name):
        self.lock = threading.Lock()
        self.messages = []  # (goal UUID bytes, feedback, DDS publication sequence number)
        node.create_subscription(action_type.Impl.FeedbackMessage, f"{action_name}/_action/feedback", self.on_feedback,
                                 QoSProfile(depth=self.DEPTH), callback_group=MutuallyExclusiveCallbackGroup())

    def on_feedback(self, msg, info):
        with self.lock:
            self.messages.append((bytes(msg.goal_id.uuid), msg.feedback, info.get("publication_sequence_number", 0)))

    def of(self, handle):
        """The goal's feedback as [(feedback, sequence number)], in arrival order."""
        uuid = bytes(handle.goal_id.uuid)
        with self.lock:
            return [(f, seq) for g, f, seq in self.messages if g == uuid]


def sequence_holes(sequence):
    """The pairs of consecutive DDS sequence numbers with something missing between them."""
    return [(a, b) for a, b in zip(sequence, sequence[1:]) if b != a + 1]


class Checker:
    def __init__(self, args):
        self.args = args
        with open(args.config) as f:
            self.config = json.load(f)
        self.names = [j["name"] for j in self.config["joints"]]
        self.spr = [j["steps_per_radian"] for j in self.config["joints"]]
        self.node = Node("armctl_check")
        self.executor = MultiThreadedExecutor(num_threads=4)
        self.executor.add_node(self.node)
        self.spin_thread = threading.Thread(target=self.executor.spin, daemon=True)
        self.spin_thread.start()
        self.lock = threading.Lock()
        self.states = []  # (receive monotonic time, JointState)
        # Per state: header.stamp, DDS source and reception timestamps, the callback (host
        # clock, s), and the DDS publication sequence number.
        self.arrivals = []
        # History 1000 (20 s at 50 Hz; was 100, 2 s): this client's callbacks ran up to 1 s
        # behind DDS reception in a Kilted .ci/run, and a reader that drops the oldest would
        # show holes in the sequence numbers that are the client's, not the bridge's.
        self.node.create_subscription(JointState, self.config.get("joint_states_topic", "/joint_states"), self.on_state, QoSProfile(depth=1000))
        # Feedback history 100 (rclpy's default 10): on a busy 2-core machine this Python
        # client may fall behind by more than 10 messages (0.33 s at 30 Hz). Its own callback
        # group, so that a slow feedback callback (check_lagging_client) holds up only it.
        fjt_name = self.config.get("action_name", "/arm_controller/follow_joint_trajectory")
        gripper_name = self.config.get("gripper_action_name", "/gripper_controller/gripper_cmd")
        self.fjt = ActionClient(self.node, FollowJointTrajectory, fjt_name,
                                feedback_sub_qos_profile=QoSProfile(depth=100), callback_group=MutuallyExclusiveCallbackGroup())
        self.gripper = ActionClient(self.node, GripperCommand, gripper_name)
        # What the bridge published, counted beside the ActionClients (see FeedbackTap).
        self.fjt_feedback = FeedbackTap(self.node, FollowJointTrajectory, fjt_name)
        self.gripper_feedback = FeedbackTap(self.node, GripperCommand, gripper_name)

    def on_state(self, msg, info):
        # Each JointState's path, on the host clock (one machine): header.stamp (the LOCATION
        # reached the bridge), the DDS source timestamp (the bridge published it), the DDS
        # reception timestamp and the callback here; `arrivals` keeps them for the figures.
        received = time.time()
        with self.lock:
            self.states.append((time.monotonic(), msg))
            self.arrivals.append((stamp_seconds(msg.header.stamp), info.get("source_timestamp", 0) * 1e-9,
                                  info.get("received_timestamp", 0) * 1e-9, received,
                                  info.get("publication_sequence_number", 0)))

    def state_count(self):
        with self.lock:
            return len(self.states)

    def states_since(self, index):
        with self.lock:
            return self.states[index:]

    def latest_positions(self):
        with self.lock:
            return list(self.states[-1][1].position) if self.states else None

    # --- graph and types -------------------------------------------------------------

    def check_graph(self):
        node_name = self.config.get("node_name", "armctl_bridge")
        action = self.config.get("action_name", "/arm_controller/follow_joint_trajectory")
        gripper = self.config.get("gripper_action_name", "/gripper_controller/gripper_cmd")
        estop = self.config.get("estop_service", "/arm_controller/estop")
        js = self.config.get("joint_states_topic", "/joint_states")
        found = wait_until(lambda: node_name in [n for n, _ in self.node.get_node_names_and_namespaces()], 20)
        check("graph: the bridge's node is listed", found, node_name)
        want_topics = {
            js: "sensor_msgs/msg/JointState",
            f"{action}/_action/feedback": "control_msgs/action/FollowJointTrajectory_FeedbackMessage",
            f"{action}/_action/status": "action_msgs/msg/GoalStatusArray",
            f"{gripper}/_action/feedback": "control_msgs/action/GripperCommand_FeedbackMessage",
        }
        want_services = {
            estop: "std_srvs/srv/Trigger",
            f"{action}/_action/send_goal": "control_msgs/action/FollowJointTrajectory_SendGoal",
            f"{action}/_action/get_result": "control_msgs/action/FollowJointTrajectory_GetResult",
            f"{action}/_action/cancel_goal": "action_msgs/srv/CancelGoal",
            f"{gripper}/_action/send_goal": "control_msgs/action/GripperCommand_SendGoal",
        }

        def graph_has_all():
            topics = dict(self.node.get_publisher_names_and_types_by_node(node_name, "/"))
            services = dict(self.node.get_service_names_and_types_by_node(node_name, "/"))
            ok = all(topics.get(t) == [ty] for t, ty in want_topics.items()) and all(
                services.get(s) == [ty] for s, ty in want_services.items())
            return (topics, services) if ok else None

        got = wait_until(graph_has_all, 15, 0.1)
        topics = dict(self.node.get_publisher_names_and_types_by_node(node_name, "/"))
        services = dict(self.node.get_service_names_and_types_by_node(node_name, "/"))
        for t, ty in want_topics.items():
            check(f"graph: topic {t}", topics.get(t) == [ty], f"{topics.get(t)}")
        for s, ty in want_services.items():
            check(f"graph: service {s}", services.get(s) == [ty], f"{services.get(s)}")
        actions = dict(get_action_names_and_types(self.node))
        check(f"graph: action {action}", actions.get(action) == ["control_msgs/action/FollowJointTrajectory"], f"{actions.get(action)}")
        check(f"graph: action {gripper}", actions.get(gripper) == ["control_msgs/action/GripperCommand"], f"{actions.get(gripper)}")
        all_topics = dict(self.node.get_topic_names_and_types())
        clock = all_topics.get("/clock")
        check("graph: /clock absent or rosgraph_msgs/msg/Clock", clock in (None, ["rosgraph_msgs/msg/Clock"]), f"{clock}")
        multi = {t: ty for t, ty in all_topics.items() if len(ty) > 1}
        check("graph: no topic with two types", not multi, f"{multi}")
        return got is not None

    def check_type_hashes(self):
        """The bridge's endpoints carry RIHS01 hashes equal to rclpy's for the same topic."""
        node_name = self.config.get("node_name", "armctl_bridge")
        action = self.config.get("action_name", "/arm_controller/follow_joint_trajectory").lstrip("/")
        estop = self.config.get("estop_service", "/arm_controller/estop").lstrip("/")
        js = self.config.get("joint_states_topic", "/joint_states").lstrip("/")
        # DDS topic names (no_mangle): ours and the bridge's endpoints on each.
        dds_topics = [
            f"rt/{js}",
            f"rt/{action}/_action/feedback",
            f"rt/{action}/_action/status",
            f"rq/{estop}Request", f"rr/{estop}Reply",
            f"rq/{action}/_action/send_goalRequest", f"rr/{action}/_action/send_goalReply",
            f"rq/{action}/_action/get_resultRequest", f"rr/{action}/_action/get_resultReply",
            f"rq/{action}/_action/cancel_goalRequest", f"rr/{action}/_action/cancel_goalReply",
        ]
        # ros_discovery_info: one writer per participant (rclpy's, the bridge's), not tied
        # to a node; every one must carry the same valid hash (the bridge's was INVALID
        # until its participant-level writer got the hash at creation).
        def discovery_writers():
            eps = self.node.get_publishers_info_by_topic("ros_discovery_info", no_mangle=True)
            return eps if len(eps) >= 2 else None
        writers = wait_until(discovery_writers, 10, 0.1) or []
        hashes = sorted({str(e.topic_type_hash) for e in writers})
        check("type hash: ros_discovery_info, every participant's writer",
              len(writers) >= 2 and len(hashes) == 1 and "INVALID" not in hashes[0],
              f"{len(writers)} writers: {hashes}")
        # Make rclpy endpoints on the service topics too (clients), for their hashes.
        estop_client = self.node.create_client(Trigger, "/" + estop)
        self.fjt.wait_for_server(timeout_sec=10)
        estop_client.wait_for_service(timeout_sec=10)
        report = {}
        all_ok = True
        for topic in dds_topics:
            def endpoints():
                eps = self.node.get_publishers_info_by_topic(topic, no_mangle=True) + \
                    self.node.get_subscriptions_info_by_topic(topic, no_mangle=True)
                bridge = [e for e in eps if e.node_name == node_name]
                ours = [e for e in eps if e.node_name == "armctl_check"]
                return (bridge, ours) if bridge and ours else None
            got = wait_until(endpoints, 10, 0.1)
            if not got:
                report[topic] = "bridge or rclpy endpoint not seen"
                all_ok = False
                continue
            bridge, ours = got
            theirs = {str(e.topic_type_hash) for e in bridge}
            mine = {str(e.topic_type_hash) for e in ours}
            ok = len(theirs) == 1 and theirs == mine and "INVALID" not in str(theirs)
            all_ok &= ok
            report[topic] = f"bridge {sorted(theirs)} rclpy {sorted(mine)}"
            check(f"type hash: {topic}", ok, report[topic])
        self.node.destroy_client(estop_client)
        figure(f"type hashes: {'all valid and equal to rclpy' if all_ok else 'NOT all valid/equal'}")
        return all_ok

    # --- joint states ------------------------------------------------------------------

    def check_joint_states(self):
        rate = self.config.get("joint_state_rate_hz", 50)
        since = time.time()
        start = self.state_count()
        got = wait_until(lambda: self.state_count() - start >= 1, 10)
        if not check("joint_states: messages arrive", got):
            return
        first = self.state_count() - 1
        window = 3.0
        t0 = self.states_since(first)[0][0]
        wait_until(lambda: self.states_since(first)[-1][0] - t0 >= window, window + 2)
        msgs = self.states_since(first)
        with self.lock:
            sequence = [a[4] for a in self.arrivals[first:first + len(msgs)]]
        span = msgs[-1][0] - msgs[0][0]
        received = (len(msgs) - 1) / span if span > 0 else 0.0
        stamps = [stamp_seconds(m.header.stamp) for _, m in msgs]
        by_stamp = (len(stamps) - 1) / (stamps[-1] - stamps[0]) if stamps[-1] > stamps[0] else 0.0
        gaps = [b - a for a, b in zip(stamps, stamps[1:])]
        median_gap = statistics.median(gaps) if gaps else 0.0
        figure(f"joint_states rate: {by_stamp:.1f} Hz by stamps, {received:.1f} Hz received ({len(msgs)} messages in {span:.3f} s); "
               f"interval by stamps {quantiles_ms(gaps)}; configured {rate} Hz")
        # The rate is sim-host's LOCATION reports (one JointState each), and on a busy machine
        # they come late: 46.2 Hz mean by stamps on Jazzy in one run here (the old bound, 10 %,
        # was 45 Hz), and in dds.sh at load 17 on 2 cores the median interval was 23.8 ms for
        # 20. The bridge's part, the report period it asks for, is checked exactly in dds.rs;
        # here the median rate by the bridge's stamps is printed and only a wrong period (a
        # unit, a factor) fails: between a third of the configured rate and 1.5 times it.
        median_hz = 1 / median_gap if median_gap > 0 else 0.0
        check("joint_states: rate by the median interval of stamps between 1/3 and 1.5 x the configured",
              rate / 3 <= median_hz <= 1.5 * rate,
              f"median {median_gap * 1000:.1f} ms: {median_hz:.1f} Hz ({by_stamp:.1f} Hz mean by stamps, {received:.1f} Hz received)")
        # None lost between the bridge's writer and this client: consecutive DDS sequence
        # numbers (0 where the RMW does not give them).
        if all(sequence):
            holes = sequence_holes(sequence)
            check("joint_states: none lost (consecutive DDS sequence numbers)", not holes, f"{len(holes)} holes: {holes[:5]}")
        self.path_figures("joint_states, arm idle", since)
        bad_names = [list(m.name) for _, m in msgs if list(m.name) != self.names]
        check("joint_states: names are the config's", not bad_names, f"{self.names}")
        on_steps = all(
            len(m.position) == len(self.names) and all(abs(p * s - round(p * s)) < 1e-6 for p, s in zip(m.position, self.spr))
            for _, m in msgs)
        check("joint_states: positions are whole steps in radians (steps / steps_per_radian)", on_steps, f"{list(msgs[-1][1].position)}")

    # --- e-stop ------------------------------------------------------------------------

    # The bound on the first call of a fresh client: one that a machine ten times slower or
    # busier than ours still meets. The bridge answers in about 1 ms (its log); the rest is
    # DDS discovery of the new client, which took up to 330 ms (Jazzy) and 219 ms (Kilted) on
    # an idle 2-core machine where a 100 ms bound failed .ci/run: ten times that is 3.3 s,
    # so 5 s (was 2 s). A call that is lost or never matched (the defect this guards) takes
    # the full 10 s wait.
    def check_estop_first_calls(self, clients=20, limit=5.0):
        service = self.config.get("estop_service", "/arm_controller/estop")
        latencies = []
        failures = []
        for i in range(clients):
            node = Node(f"estop_client_{i}")
            executor = SingleThreadedExecutor()
            executor.add_node(node)
            try:
                client = node.create_client(Trigger, service)
                if not client.wait_for_service(timeout_sec=10):
                    failures.append(f"client {i}: service not found in 10 s")
                    continue
                answered = {}
                t0 = time.monotonic()
                future = client.call_async(Trigger.Request())
                future.add_done_callback(lambda _f: answered.setdefault("t", time.monotonic()))
                executor.spin_until_future_complete(future, timeout_sec=10)
                if not future.done():
                    failures.append(f"client {i}: no answer in 10 s")
                    continue
                latencies.append(answered.get("t", time.monotonic()) - t0)
                if not future.result().success:
                    failures.append(f"client {i}: success false: {future.result().message}")
            finally:
                executor.remove_node(node)
                node.destroy_node()
                executor.shutdown()
        ms = sorted(x * 1000 for x in latencies)
        if ms:
            figure(f"e-stop first call over {len(ms)} fresh clients: {quantiles_ms(latencies)}, "
                   f"over 100 ms: {sum(1 for x in ms if x > 100)}; all: {', '.join(f'{x:.0f}' for x in ms)}")
        check(f"e-stop: {clients} fresh clients answered", not failures and len(latencies) == clients, "; ".join(failures))
        check(f"e-stop: every first call within {limit:.0f} s", latencies and max(latencies) <= limit,
              f"{sum(1 for x in latencies if x > limit)} of {len(latencies)} over")

    # --- trajectories ------------------------------------------------------------------

    def in_executor(self, call, timeout=10):
        """call() run by the executor, in the node's default callback group (the action
        clients' and the subscription's: mutually exclusive), so that no callback of the
        action clients runs meanwhile. rclpy Jazzy's send_goal_async from this thread raced
        with the executor thread taking the answer (ValueError: list.remove(x): x not in
        list, in _remove_pending_request; seen once in rclpy.sh on a busy machine)."""
        done = threading.Event()
        box = {}

        def once():
            timer.cancel()
            try:
                box["value"] = call()
            except Exception as e:  # raised again in the caller's thread
                box["error"] = e
            finally:
                done.set()

        timer = self.node.create_timer(0.0, once)
        finished = done.wait(timeout)
        self.node.destroy_timer(timer)
        if "error" in box:
            raise box["error"]
        return box.get("value") if finished else None

    def result_of(self, call, timeout):
        """The result of the future that call() returns (made in the executor), or None."""
        future = self.in_executor(call)
        return wait_future(future, timeout) if future is not None else None

    def send_goal(self, client, goal, feedback=None, timeout=10):
        if not client.wait_for_server(timeout_sec=timeout):
            return None
        return self.result_of(lambda: client.send_goal_async(goal, feedback_callback=feedback), timeout)

    def moveit_goal(self, start, target, seconds, points=11):
        """A MoveIt-style goal: smoothstep positions with their velocities."""
        goal = FollowJointTrajectory.Goal()
        goal.trajectory.joint_names = list(self.names)
        for k in range(points):
            s = k / (points - 1)
            shape = 3 * s * s - 2 * s ** 3
            slope = (6 * s - 6 * s * s) / seconds
            p = JointTrajectoryPoint()
            p.positions = [a + (b - a) * shape for a, b in zip(start, target)]
            p.velocities = [(b - a) * slope for a, b in zip(start, target)]
            p.time_from_start = duration(seconds * s)
            goal.trajectory.points.append(p)
        return goal

    def small_goal(self, seconds, feedback_callback=None):
        """A goal moving each joint 0.01 rad in `seconds`; returns its handle once the
        result is in and joint_states show the goal's end (bounded), or None."""
        start = self.latest_positions()
        target = [p + 0.01 for p in start]
        handle = self.send_goal(self.fjt, self.moveit_goal(start, target, seconds), feedback_callback)
        if handle is None or not handle.accepted:
            return None
        self.result_of(handle.get_result_async, 30)
        # The next goal starts where joint_states say the arm is: wait (bounded) until they
        # show this goal's end. A busy client got its result before the JointState of the
        # end (seen once in .ci/run on Kilted: the measured goal planned from 0.0 rad with
        # the arm at 0.01 rad, and the bridge refused it for the start tolerance).
        want = [round(t * s) for t, s in zip(target, self.spr)]
        wait_until(lambda: [round(p * s) for p, s in zip(self.latest_positions(), self.spr)] == want, 5)
        return handle

    def feedback_figures(self, handle, seconds):
        """The goal's feedback on the topic, once at least 80 % of rate x `seconds` have
        arrived (bounded: this client may take them well after the result): the rate by the
        bridge's stamps (when it made each; the arrival times of this Python client on a busy
        machine say more about the client), the count, the holes in the DDS sequence numbers."""
        rate = self.config.get("feedback_rate_hz", 30)
        wanted = 0.8 * rate * seconds
        wait_until(lambda: len(self.fjt_feedback.of(handle)) >= wanted, 5)
        tapped = self.fjt_feedback.of(handle)
        stamps = [stamp_seconds(f.header.stamp) for f, _ in tapped]
        span = stamps[-1] - stamps[0] if len(stamps) >= 2 else 0.0
        fb_rate = (len(stamps) - 1) / span if span > 0 else 0.0
        gaps = [b - a for a, b in zip(stamps, stamps[1:])]
        sequence = [seq for _, seq in tapped]
        holes = sequence_holes(sequence) if all(sequence) else []  # 0: the RMW gives none
        ok = fb_rate >= 0.8 * rate and len(tapped) >= wanted and not holes
        text = (f"{fb_rate:.1f} Hz by stamps ({len(tapped)} messages over {span:.3f} s, largest gap "
                f"{max(gaps, default=0) * 1000:.0f} ms, {len(holes)} holes in the DDS sequence numbers: {holes[:5]}); "
                f"configured {rate} Hz, {rate * seconds:.0f} expected")
        return ok, text, tapped

    def check_lagging_client(self):
        """Regression (Kilted .ci/run, 2026-11-29; see FeedbackTap): a client whose feedback
        callback runs behind (100 ms each, a third of the rate) still sees on the feedback
        topic every message the bridge sent. The ActionClient's own count is printed: rclpy
        drops what it takes after the result, which is what the old check counted."""
        called = []
        handle = self.small_goal(1.0, lambda f: (called.append(f), time.sleep(0.1)))
        if not check("lagging client: a 1 s goal accepted", handle is not None):
            return
        ok, text, tapped = self.feedback_figures(handle, 1.0)
        figure(f"lagging client (100 ms per feedback callback): the ActionClient's callback got {len(called)}, "
               f"the feedback topic {len(tapped)}")
        check("lagging client: the feedback topic has every message, at >= 80% of the configured rate", ok, text)

    def check_goal_with_velocities(self):
        since = time.time()
        # A short goal first, its feedback not counted: the bridge's feedback writer
        # matches a reader only once discovery has run both ways, and a reliable volatile
        # writer sends nothing to a reader it has not matched yet. A MoveIt client lives long
        # before its goals; this one was just made (seen once in .ci/run on Kilted: the first
        # 57 of 60 messages of the measured goal lost to a late match).
        warm = self.small_goal(0.5)
        figure(f"warm-up goal (0.5 s, not counted): {len(self.fjt_feedback.of(warm)) if warm else 0} feedback messages")
        self.check_lagging_client()
        start = self.latest_positions()
        target = [0.3, -0.2, 0.4, 0.5, -0.6, 0.7]
        goal = self.moveit_goal(start, target, 2.0)
        feedback = []
        handle = self.send_goal(self.fjt, goal, lambda f: feedback.append(f.feedback))
        if not check("goal with velocities: accepted", handle is not None and handle.accepted):
            return
        result = self.result_of(handle.get_result_async, 30)
        status = result.status if result else None
        code = result.result.error_code if result else None
        check("goal with velocities: SUCCEEDED, SUCCESSFUL", status == GoalStatus.STATUS_SUCCEEDED and code == 0,
              f"status {status} code {code} {result.result.error_string if result else 'no result in 30 s'}")
        ok, text, tapped = self.feedback_figures(handle, 2.0)
        figure(f"FollowJointTrajectory feedback: {text}; {len(feedback)} reached the ActionClient's callback")
        check("goal with velocities: feedback at >= 80% of the configured rate, none lost", ok, text)
        last = tapped[-1][0] if tapped else None
        check("goal with velocities: feedback names and actual positions",
              last is not None and list(last.joint_names) == self.names and len(last.actual.positions) == 6,
              f"{list(last.joint_names) if last else 'no feedback'}")
        # The arm ends exactly at the goal steps: JointStates received after the result may
        # lag behind (a busy client), so wait (bounded) for one at the goal, then check it
        # is still there 10 messages later.
        want = [round(t * s) for t, s in zip(target, self.spr)]
        steps = lambda: [round(p * s) for p, s in zip(self.latest_positions(), self.spr)]
        wait_until(lambda: steps() == want, 5)
        n = self.state_count()
        wait_until(lambda: self.state_count() >= n + 10, 2)
        got = steps()
        self.path_figures("goals with velocities", since)
        check("goal with velocities: joint_states at exactly the goal steps", got == want, f"steps {got}, goal {want}")

    def path_figures(self, what, since):
        """Prints where the JointStates received after host time `since` spent their time:
        in the bridge (LOCATION arrival, header.stamp, to DDS write), in DDS (write to
        reception) and in this client (reception to callback)."""
        with self.lock:
            arrivals = [a for a in self.arrivals if a[3] >= since]
        if not arrivals or not all(a[1] and a[2] for a in arrivals):
            figure(f"{what}: JointState path: no DDS timestamps ({len(arrivals)} states)")
            return
        figure(f"{what}: JointState path over {len(arrivals)} states: "
               f"bridge (stamp to publish) {quantiles_ms([a[1] - a[0] for a in arrivals])}; "
               f"DDS (publish to reception) {quantiles_ms([a[2] - a[1] for a in arrivals])}; "
               f"client (reception to callback) {quantiles_ms([a[3] - a[2] for a in arrivals])}")

    def check_cancel(self):
        start = self.latest_positions()
        target = [-0.5, 0.5, -0.6, -0.8, 0.8, -0.9]
        goal = self.moveit_goal(start, target, 4.0)
        handle = self.send_goal(self.fjt, goal)
        if not check("cancel: goal accepted", handle is not None and handle.accepted):
            return
        # Wait until the arm has moved (observed in joint_states), then cancel.
        moved = wait_until(lambda: any(abs(a - b) > 0.05 for a, b in zip(self.latest_positions(), start)), 5)
        check("cancel: the arm moves", moved)
        cancel_sent = time.time()
        cancel = self.result_of(handle.cancel_goal_async, 5)
        check("cancel: accepted", cancel is not None and len(cancel.goals_canceling) == 1, f"{cancel}")
        result = self.result_of(handle.get_result_async, 10)
        result_at = time.time()
        status = result.status if result else None
        check("cancel: CANCELED", status == GoalStatus.STATUS_CANCELED, f"status {status} {result.result.error_string if result else ''}")
        # No step after the cancel: the 26 JointStates stamped after the CANCELED result came
        # here (0.5 s at 50 Hz) are all the same. Chosen by header.stamp (when the LOCATION
        # reached the bridge), not by arrival here: states of before the stop that this
        # client's executor takes after the result (Jazzy on a busy 2-core machine: 0.4 s of
        # them) say nothing about the arm after it.
        def stamped_after():
            with self.lock:
                return [list(m.position) for (_, m), a in zip(self.states, self.arrivals) if a[0] > result_at]
        n = self.state_count()
        wait_until(lambda: len(stamped_after()) >= 26, 5)
        after = stamped_after()
        with self.lock:
            late = [(a, list(m.position)) for (_, m), a in zip(self.states[n:], self.arrivals[n:]) if a[0] <= result_at]
        figure(f"cancel: {len(late)} JointStates received after the CANCELED result were stamped before it"
               + (f" (oldest {(result_at - min(a[0] for a, _ in late)) * 1000:.0f} ms before; "
                  f"moved {sum(1 for (_, p), (_, q) in zip(late, late[1:]) if p != q)} times among them)" if late else ""))
        self.path_figures("cancel", cancel_sent)
        still = len(after) >= 26 and all(p == after[0] for p in after)
        check("cancel: positions stop changing", still and any(abs(a - b) > 0.05 for a, b in zip(after[0], start)),
              f"{len(after)} states stamped after the result, first {after[0] if after else None}, last {after[-1] if after else None}")

    def check_wrong_names(self):
        goal = FollowJointTrajectory.Goal()
        goal.trajectory.joint_names = ["base", "not_a_joint"]
        p = JointTrajectoryPoint()
        p.positions = [0.0, 0.0]
        p.time_from_start = duration(1.0)
        goal.trajectory.points.append(p)
        handle = self.send_goal(self.fjt, goal)
        result = self.result_of(handle.get_result_async, 10) if handle and handle.accepted else None
        status = result.status if result else None
        code = result.result.error_code if result else None
        check("wrong joint names: ABORTED, INVALID_JOINTS", status == GoalStatus.STATUS_ABORTED and code == FollowJointTrajectory.Result.INVALID_JOINTS,
              f"status {status} code {code}: {result.result.error_string if result else ''}")

    def check_speed_scaling_and_hold(self):
        """Issue 32, as UR's driver offers it: the speed scaling input (std_msgs/Float64, a
        fraction) slows a goal, its state (percent) says so; the hold service stops a goal
        part way (state 0, joint_states still), the resume service lets it end exactly at
        its goal. Durations are only bounded from below (a busy machine makes them longer)."""
        scaling_in = self.config.get("speed_scaling_topic", "/arm_controller/speed_scaling_factor")
        scaling_state = self.config.get("speed_scaling_state_topic", "/speed_scaling_state_broadcaster/speed_scaling")
        states = []
        sub = self.node.create_subscription(Float64, scaling_state, lambda m: states.append(m.data), QoSProfile(depth=100))
        pub = self.node.create_publisher(Float64, scaling_in, QoSProfile(depth=10))
        hold = self.node.create_client(Trigger, self.config.get("hold_service", "/arm_controller/hold"))
        resume = self.node.create_client(Trigger, self.config.get("resume_service", "/arm_controller/resume"))
        try:
            matched = wait_until(lambda: pub.get_subscription_count() > 0, 10)
            check("speed scaling: the bridge subscribes to the input", matched, scaling_in)
            shows = lambda want: wait_until(lambda: any(abs(v - want) < 0.05 for v in states[-3:]), 10)
            check("speed scaling: state published, 100 %", shows(100.0), f"last {states[-3:]}")
            pub.publish(Float64(data=0.5))
            check("speed scaling: 0.5 taken, state 50 %", shows(50.0), f"last {states[-3:]}")
            start = self.latest_positions()
            out = list(start)
            out[0] += 0.2
            goal = FollowJointTrajectory.Goal()
            goal.trajectory.joint_names = list(self.names)
            goal.trajectory.points = [JointTrajectoryPoint(positions=out, time_from_start=duration(1.0))]
            sent = time.monotonic()
            handle = self.send_goal(self.fjt, goal)
            result = self.result_of(handle.get_result_async, 60) if handle is not None and handle.accepted else None
            took = time.monotonic() - sent
            figure(f"1 s goal at speed scaling 0.5: {took:.3f} s from the goal sent to its result")
            check("speed scaling 0.5: a 1 s goal SUCCEEDED, taking at least 1.9 s",
                  result is not None and result.status == GoalStatus.STATUS_SUCCEEDED and took >= 1.9,
                  f"{took:.3f} s, {result.result.error_string if result else 'no result'}")
            pub.publish(Float64(data=1.0))
            check("speed scaling: 1.0 taken, state 100 %", shows(100.0), f"last {states[-3:]}")
            # Back over 4 s, held once joint_states show the arm moving, resumed once it stood
            # still. Not a fixed 0.6 s into a 2 s goal: this client's executor, which sends the
            # hold, can run 1 s behind on a busy machine, and the goal must still be under way.
            steps = lambda: [round(p * s) for p, s in zip(self.latest_positions(), self.spr)]
            want = [round(p * s) for p, s in zip(start, self.spr)]
            goal.trajectory.points = [JointTrajectoryPoint(positions=start, time_from_start=duration(4.0))]
            handle = self.send_goal(self.fjt, goal)
            if not check("hold: goal accepted", handle is not None and handle.accepted):
                return
            moving = wait_until(lambda: abs(self.latest_positions()[0] - out[0]) > 0.01, 10)
            check("hold: the arm moves before the hold", moving, f"joint 0 at {self.latest_positions()[0]:.4f} rad, left {out[0]:.4f}")
            held = self.result_of(lambda: hold.call_async(Trigger.Request()), 10)
            check("hold: the service answers success", held is not None and held.success, f"{held}")
            check("hold: state 0 % (at rest)", shows(0.0), f"last {states[-3:]}")
            # By the bridge's stamps: this client may take JointStates up to ~1 s late (see
            # check_cancel), and those of before the stop must not count.
            rest_at = time.time()
            n = self.state_count()
            after = lambda: [m for _, m in self.states_since(n) if stamp_seconds(m.header.stamp) >= rest_at]
            wait_until(lambda: len(after()) >= 20, 10)
            still = [[round(p * s) for p, s in zip(m.position, self.spr)] for m in after()[:20]]
            check("hold: 20 joint_states all equal, part way",
                  len(still) == 20 and all(p == still[0] for p in still) and still[0] != want,
                  f"{len(still)} states, first {still[0] if still else None}, goal {want}")
            resumed = self.result_of(lambda: resume.call_async(Trigger.Request()), 10)
            check("resume: the service answers success", resumed is not None and resumed.success, f"{resumed}")
            result = self.result_of(handle.get_result_async, 60)
            check("resume: the held goal SUCCEEDED", result is not None and result.status == GoalStatus.STATUS_SUCCEEDED,
                  f"{result.result.error_string if result else 'no result'}")
            wait_until(lambda: steps() == want, 5)
            check("resume: joint_states at exactly the goal steps", steps() == want, f"steps {steps()}, goal {want}")
            figure(f"hold: stood at {still[0][0] if still else None} steps of joint 0 (from {round(out[0] * self.spr[0])} to {want[0]})")
        finally:
            self.node.destroy_subscription(sub)
            self.node.destroy_publisher(pub)
            self.node.destroy_client(hold)
            self.node.destroy_client(resume)

    def check_gripper(self):
        if "gripper" not in self.config:
            return
        goal = GripperCommand.Goal()
        goal.command.position = 0.04
        handle = self.send_goal(self.gripper, goal)
        result = self.result_of(handle.get_result_async, 10) if handle and handle.accepted else None
        ok = result is not None and result.status == GoalStatus.STATUS_SUCCEEDED and result.result.reached_goal \
            and abs(result.result.position - 0.04) < 1e-9
        check("gripper: a goal at 0.04 m SUCCEEDS at 0.04 m", ok, f"{result.result if result else 'no result'}")
        # Counted on the topic (see FeedbackTap), bounded: this client may take it after the result.
        feedback = lambda: [f for f, _ in self.gripper_feedback.of(handle)] if handle else []
        wait_until(lambda: len(feedback()) >= 1, 5)
        got = feedback()
        check("gripper: feedback", len(got) >= 1 and abs(got[0].position - 0.04) < 1e-9, f"{len(got)} messages")
        goal.command.position = 5.0
        handle = self.send_goal(self.gripper, goal)
        check("gripper: a goal at 5 m is rejected", handle is not None and not handle.accepted, f"{handle.accepted if handle else 'no answer'}")

    def close(self):
        self.executor.shutdown()
        # The spin thread ends before the node goes: destroyed under a wait it raised
        # "cannot use Destroyable" (once, Kilted, under a concurrent .ci/run).
        self.spin_thread.join(5)
        self.node.destroy_node()


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--distro", required=True)
    ap.add_argument("--sim-host", required=True)
    ap.add_argument("--bridge", required=True)
    ap.add_argument("--config", required=True)
    ap.add_argument("--port", default="8510")
    args = ap.parse_args()
    work = tempfile.mkdtemp(prefix="rclpy-check-")
    addr = f"127.0.0.1:{args.port}"
    with open(args.config) as f:
        config = json.load(f)
    config["controller"] = addr
    config["ros_distro"] = args.distro
    config_path = os.path.join(work, "bridge.json")
    with open(config_path, "w") as f:
        json.dump(config, f)
    args.config = config_path

    procs = []
    try:
        sim = subprocess.Popen([args.sim_host, "--bind", addr, "--joints", "6", "--settings", os.path.join(work, "settings.txt"), "--log-level", "warn"])
        procs.append(sim)
        env = dict(os.environ, RUST_LOG=os.environ.get("RUST_LOG", "info,rustdds=warn,ros2_client=warn"))
        bridge_log = open(os.path.join(work, "bridge.log"), "w")
        # The bridge retries until sim-host answers (it exits at once if the controller is not there yet).
        deadline = time.monotonic() + 15
        while True:
            bridge = subprocess.Popen([args.bridge, config_path], env=env, stdout=bridge_log, stderr=subprocess.STDOUT)
            time.sleep(0.3)
            if bridge.poll() is None or time.monotonic() > deadline:
                break
        procs.append(bridge)
        if not check("bridge started on sim-host", bridge.poll() is None):
            print(open(os.path.join(work, "bridge.log")).read())
            return 1

        rclpy.init()
        checker = Checker(args)
        try:
            checker.check_graph()
            checker.check_type_hashes()
            checker.check_joint_states()
            checker.check_estop_first_calls()
            checker.check_goal_with_velocities()
            checker.check_cancel()
            checker.check_wrong_names()
            checker.check_gripper()
            checker.check_speed_scaling_and_hold()
        finally:
            checker.close()
            rclpy.try_shutdown()
        check("bridge still running", bridge.poll() is None)
    finally:
        for p in reversed(procs):
            p.terminate()
            try:
                p.wait(5)
            except subprocess.TimeoutExpired:
                p.kill()
        log = open(os.path.join(work, "bridge.log")).read()
        if "ARMCTL_CHECK_LOG" in os.environ or any(not ok for _, ok in RESULTS):
            print("--- bridge log (last 40 lines)")
            print("\n".join(log.splitlines()[-40:]))
    passed = sum(1 for _, ok in RESULTS if ok)
    failed = len(RESULTS) - passed
    print(f"rclpy {args.distro}: {passed} passed, {failed} failed")
    return 0 if failed == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
