"""The shipped Zenoh roles (field/link/zenoh_acl.json5, defect 4): only the crane serves commands
and publishes status / outcome / liveliness, only operators command, observers only read — each
role's rights and denials, on the crane's own node and through a router. Loopback only."""

from __future__ import annotations

import json
import time

import pytest

from field.controller import read_execution_log
from field.errors import LinkError
from field.link import ControllerState, open_link
from field.link.base import LinkConfig
from field.link.codec import Encoder
from field.link.messages import Outcome, OutcomeClass
from field.link.zenoh_backend import ZenohKeys
from tests.field.helpers import PASSWORDS, credentials, shipped_acl, wait_until

FAST = LinkConfig(insecure=True, heartbeat_timeout_s=1.0, connect_timeout_s=10.0)
SHORT = LinkConfig(insecure=True, connect_timeout_s=2.0)
def session(port: int, user: str, mode: str = "client"):
    import zenoh

    c = zenoh.Config()
    for key, value in (("mode", json.dumps(mode)), ("connect/endpoints", json.dumps([f"tcp/127.0.0.1:{port}"])),
                       ("listen/endpoints", "[]"), ("scouting/multicast/enabled", "false"),
                       ("scouting/gossip/enabled", "false"), ("transport/auth/usrpwd/user", json.dumps(user)),
                       ("transport/auth/usrpwd/password", json.dumps(PASSWORDS[user]))):
        c.insert_json5(key, value)
    return zenoh.open(c)


@pytest.fixture
def sessions():
    made = []

    def make(port: int, user: str):
        s = session(port, user)
        made.append(s)
        return s

    yield make
    for s in made:
        s.close()


def ok_replies(s, key: str, payload: bytes) -> list[bytes]:
    return [r.ok.payload.to_bytes() for r in s.get(key, payload=payload, timeout=1.5) if r.ok is not None]


# --- on the crane's own node ----------------------------------------------------------------


@pytest.mark.safety_case(error="masquerade", link="zenoh",
                         measure="access-control roles by authenticated user: only the crane serves",
                         reaction="an operator or observer cannot pose as the crane; an observer cannot command")
def test_roles_on_the_crane_node(port, controller_process, tmp_path, sessions, make_cmd):
    url = f"zenoh://127.0.0.1:{port}/crane-n"
    controller_process(f"{url}?config={shipped_acl(tmp_path)}")
    keys = ZenohKeys("loggrasp/crane-n")
    # the operator commands: command, ack, outcome, status, e-stop
    with open_link(f"{url}?config={credentials(tmp_path, 'operator')}", FAST) as link:
        cmd = make_cmd(link.new_command_id())
        assert link.send_grasp(cmd, timeout_s=5.0).accepted
        assert link.wait_outcome(cmd.command_id, 10.0).success
        # an operator account cannot impersonate the crane: serve, reply, publish
        rogue = sessions(port, "operator")
        watcher = sessions(port, "observer")
        seen: list[bytes] = []
        watcher.declare_subscriber(keys.outcome, lambda smp: seen.append(smp.payload.to_bytes()))
        forged = Encoder().encode(Outcome(cmd.command_id, OutcomeClass.SUCCESS, 9, 1000))[1]
        rogue.declare_queryable(keys.cmd, lambda q: q.reply(q.key_expr, forged))
        time.sleep(0.5)  # let the (denied) declarations propagate if they were allowed
        rogue.put(keys.outcome, forged)
        replies = ok_replies(link._session, keys.cmd, b"not a frame")
        assert replies and forged not in replies  # only the crane answers (here: MALFORMED)
        second = make_cmd(link.new_command_id())
        assert link.send_grasp(second, timeout_s=5.0).accepted
        assert link.wait_outcome(second.command_id, 10.0).success
        assert wait_until(lambda: len(seen) >= 1)  # the observer reads the crane's outcome ...
        assert forged not in seen  # ... and never the forged one
        # the observer reads only: no commands, no status queries, no e-stops
        assert ok_replies(watcher, keys.cmd, Encoder().encode(make_cmd(4242))[1]) == []
        assert ok_replies(watcher, keys.status, b"") == []
        watcher.put(keys.estop, b"stop")
        time.sleep(0.5)
        assert link.status().state is not ControllerState.ESTOP
        assert link.abort(timeout_s=5.0).state is ControllerState.ESTOP  # the operator's e-stop works
    with pytest.raises(LinkError, match="controller"):
        open_link(f"{url}?config={credentials(tmp_path, 'observer')}", SHORT)  # an observer is no laptop
    assert read_execution_log(tmp_path / "executed.jsonl") == [cmd.command_id, second.command_id]


def test_ros2_publications_pass_the_roles(port, controller_process, tmp_path, sessions):
    """An operator's laptop publishes the ROS 2 grasp; an observer (a ROS 2 crane stack) receives it
    and sees the laptop's node in the graph; an observer cannot publish a grasp of its own."""
    from field.ros2 import POSE_STAMPED, grasp_pose_map, topic_key

    url = f"zenoh://127.0.0.1:{port}/crane-r"
    controller_process(f"{url}?config={shipped_acl(tmp_path)}")
    key = topic_key(0, "/loggrasp/crane-r/grasp", POSE_STAMPED)
    with open_link(f"{url}?config={credentials(tmp_path, 'operator')}", FAST) as link:
        ros = link.ros2_publisher()
        watcher = sessions(port, "observer")
        seen: list[bytes] = []
        watcher.declare_subscriber(key, lambda smp: seen.append(smp.payload.to_bytes()))
        operators_view: list[bytes] = []
        link._session.declare_subscriber(key, lambda smp: operators_view.append(smp.payload.to_bytes()))
        time.sleep(0.5)
        ros.publish_grasp(1.0, grasp_pose_map(743497.0, 7117716.0, 250.0, 30.0), 1)
        assert wait_until(lambda: len(seen) >= 1)
        tokens = [str(r.ok.key_expr) for r in watcher.liveliness().get("@ros2_lv/**", timeout=2.0) if r.ok]
        assert any("/NN/" in t for t in tokens) and any("/MP/" in t for t in tokens), tokens
        watcher.put(key, b"forged")
        time.sleep(0.5)
        assert operators_view and b"forged" not in operators_view  # it hears the grasp, never the forgery


# --- through a router -----------------------------------------------------------------------


@pytest.fixture
def router(port, tmp_path):
    """A Zenoh router on 127.0.0.1 enforcing the shipped roles (the crane connects to it too)."""
    import zenoh

    conf = zenoh.Config.from_file(shipped_acl(tmp_path))
    for key, value in (("mode", '"router"'), ("listen/endpoints", json.dumps([f"tcp/127.0.0.1:{port}"])),
                       ("connect/endpoints", "[]"), ("scouting/multicast/enabled", "false"),
                       ("scouting/gossip/enabled", "false")):
        conf.insert_json5(key, value)
    r = zenoh.open(conf)
    yield port
    r.close()


def test_roles_through_a_router(router, controller_process, tmp_path, sessions, make_cmd):
    port = router
    crane = controller_process(f"zenoh://crane-r?config={shipped_acl(tmp_path, connect=f'tcp/127.0.0.1:{port}')}")
    url = f"zenoh://127.0.0.1:{port}/crane-r"
    keys = ZenohKeys("loggrasp/crane-r")
    with open_link(f"{url}?config={credentials(tmp_path, 'operator')}", FAST) as link:  # the crane role serves
        cmd = make_cmd(link.new_command_id())
        assert link.send_grasp(cmd, timeout_s=5.0).accepted
        assert link.wait_outcome(cmd.command_id, 10.0).success
    crane.kill()
    crane.stop()
    # with the crane gone, an operator account plays crane: token, queryable, status
    rogue = sessions(port, "operator")
    forged = Encoder().encode(Outcome(1, OutcomeClass.SUCCESS, 1, 1000))[1]
    rogue.liveliness().declare_token(keys.alive_controller)
    rogue.declare_queryable(keys.cmd, lambda q: q.reply(q.key_expr, forged))
    rogue.declare_queryable(keys.status, lambda q: q.reply(q.key_expr, forged))
    time.sleep(0.5)
    tokens: list[str] = []
    watcher = sessions(port, "operator")
    watcher.liveliness().declare_subscriber(f"{keys.prefix}/alive/**", lambda s: tokens.append(str(s.key_expr)),
                                            history=True)
    assert ok_replies(watcher, keys.cmd, b"x") == []  # no reply from the would-be crane
    time.sleep(0.5)
    assert keys.alive_controller not in tokens  # its token is not forwarded
    with pytest.raises(LinkError, match="controller"):
        open_link(f"{url}?config={credentials(tmp_path, 'operator')}", SHORT)
    assert read_execution_log(tmp_path / "executed.jsonl") == [cmd.command_id]
