"""An e-stop whose frame cannot be sent says why (issue 39): ``CraneLink.abort`` keeps the last
transmit error, names it in the LinkTimeout it raises (and chains it), and logs it - on CAN and on
Zenoh. Before, the retry loop swallowed every error and said only "not confirmed"."""

from __future__ import annotations

import logging

import can
import pytest

from field.controller import ControllerConfig, controller_in_thread
from field.errors import LinkTimeout
from field.link import ControllerState, LinkConfig, open_link
from tests.field.helpers import can_pairs

LINK = LinkConfig(insecure=True, heartbeat_timeout_s=1.0, status_timeout_s=0.3, connect_timeout_s=10.0)


def _estop_error(link, caplog) -> LinkTimeout:
    with caplog.at_level(logging.ERROR), pytest.raises(LinkTimeout) as info:
        link.abort(timeout_s=1.0)
    exc = info.value
    assert exc.__cause__ is link.last_estop_error is not None, "the transmit error is kept and chained"
    assert type(link.last_estop_error).__name__ in str(exc) and "USE THE PHYSICAL E-STOP" in str(exc)
    assert any("could not send the e-stop frame" in r.getMessage() for r in caplog.records), "and logged"
    return exc


@pytest.mark.safety_case(abort="an e-stop whose transmission fails", link="can",
                         reaction="the last transmit error is kept, logged and named to the operator (USE THE PHYSICAL "
                                  "E-STOP)")
def test_can_an_estop_that_cannot_be_sent_names_the_bus_error(caplog):
    with can_pairs("estop", LINK) as make:
        p = make()
        p.lbus.arm("error", "EStop", count=None)  # the bus refuses every e-stop frame
        exc = _estop_error(p.link, caplog)
        assert isinstance(p.link.last_estop_error, can.CanOperationError)
        assert "injected bus error on send" in str(exc)
        assert p.controller.state is not ControllerState.ESTOP
        p.lbus.disarm()
        assert p.link.abort(timeout_s=5.0).state is ControllerState.ESTOP  # the bus is back: it stops


@pytest.mark.safety_case(abort="an e-stop whose transmission fails", link="zenoh",
                         reaction="the last transmit error is kept, logged and named to the operator (USE THE PHYSICAL "
                                  "E-STOP)")
def test_zenoh_an_estop_that_cannot_be_sent_names_the_session_error(port, caplog):
    url = f"zenoh://127.0.0.1:{port}/crane-estop"
    with controller_in_thread(url, "fixed", ControllerConfig(no_journal=True, insecure_link=True), start_timeout_s=20.0):
        link = open_link(url, LINK)
        try:
            link._session.close()  # the session underneath is gone: every put fails
            _estop_error(link, caplog)
        finally:
            link.close()
