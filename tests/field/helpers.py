"""Small helpers of the field tests (import as ``tests.field.helpers``)."""

from __future__ import annotations

import json
import os
import time
from importlib import resources
from typing import Callable

#: how long a test waits for something that should happen "at once" [s]: generous, so that a
#: loaded 2-core machine never fails a test that is right (the wait ends as soon as it holds)
PATIENCE_S = 10.0


def wait_until(predicate: Callable[[], bool], timeout_s: float = PATIENCE_S, poll_s: float = 0.01) -> bool:
    """Poll ``predicate`` until it is true (returns True) or ``timeout_s`` passed (False)."""
    deadline = time.monotonic() + timeout_s
    while True:
        if predicate():
            return True
        if time.monotonic() >= deadline:
            return False
        time.sleep(poll_s)


# --- Zenoh roles (the shipped field/link/zenoh_acl.json5) ----------------------------------

PASSWORDS = {"crane": "crane-secret", "operator": "op-secret", "observer": "obs-secret"}


def shipped_acl(tmp_path, *, connect: str | None = None) -> str:
    """The shipped config with this test's user file (and, for a crane behind a router, the
    router to connect to); returns the path of the JSON file (JSON is JSON5)."""
    import zenoh

    users = tmp_path / "users.txt"
    users.write_text("".join(f"{u}:{p}\n" for u, p in PASSWORDS.items()))
    os.chmod(users, 0o600)
    conf = zenoh.Config.from_file(str(resources.files("field.link").joinpath("zenoh_acl.json5")))
    conf.insert_json5("transport/auth/usrpwd/dictionary_file", json.dumps(str(users)))
    conf.insert_json5("transport/auth/usrpwd/password", json.dumps(PASSWORDS["crane"]))
    if connect is not None:  # the crane behind a router: the router enforces the roles
        for key, value in (("mode", '"client"'), ("connect/endpoints", json.dumps([connect])),
                           ("access_control/enabled", "false"),
                           ("listen/endpoints", "[]"), ("scouting/multicast/enabled", "false"),
                           ("scouting/gossip/enabled", "false")):
            conf.insert_json5(key, value)
    path = tmp_path / ("crane-client.json" if connect else "crane-node.json")
    path.write_text(str(conf))
    return str(path)


def credentials(tmp_path, user: str) -> str:
    path = tmp_path / f"{user}.json"
    path.write_text(json.dumps({"transport": {"auth": {"usrpwd": {"user": user, "password": PASSWORDS[user]}}}}))
    return str(path)
