import gc

import pytest


@pytest.fixture(autouse=True)
def state_home_in_tmp(tmp_path_factory, monkeypatch):
    """Default files under $XDG_STATE_HOME (a controller's journal) go to a temporary folder, never
    to the user's ~/.local/state."""
    monkeypatch.setenv("XDG_STATE_HOME", str(tmp_path_factory.mktemp("state")))


@pytest.fixture(autouse=True)
def no_leaked_pybullet_clients():
    """Fail a test that leaves a pybullet client connected (every World must be closed)."""
    import pybullet as p

    def connected() -> int:
        return sum(p.isConnected(i) for i in range(64))

    before = connected()
    yield
    gc.collect()
    after = connected()
    assert after <= before, f"test leaked {after - before} pybullet client(s): close every World"


# the command-line tests' scratch folder and a plain file (tests/cli_helpers.py has the runner)
@pytest.fixture(scope="module")
def work(tmp_path_factory):
    return tmp_path_factory.mktemp("cli")


@pytest.fixture(scope="module")
def a_file(work):
    """A plain file: an output path under it can never be made (also as root)."""
    f = work / "a_file"
    f.write_text("x")
    return f
