import gc

import pytest


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
