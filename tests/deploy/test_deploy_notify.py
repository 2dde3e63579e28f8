"""tactiled.systemd against a real notification socket: exact datagrams, watchdog rules."""

from __future__ import annotations

import asyncio
import logging
import os

import pytest
from deploy_helpers import NotifySocket

from tactiled.systemd import MAX_STATUS, Notifier, WatchdogGate, watchdog_interval, watchdog_loop


def test_messages_arrive_exactly_on_a_path_socket(notify_socket):
    n = Notifier.from_env({"NOTIFY_SOCKET": notify_socket.address})
    assert n.enabled
    assert n.ready() and n.status("2 sensors, 1 worker") and n.watchdog() and n.stopping()
    got = [notify_socket.recv() for _ in range(4)]
    assert [m.data for m in got] == [b"READY=1", b"STATUS=2 sensors, 1 worker", b"WATCHDOG=1",
                                     b"STOPPING=1"]
    assert {m.pid for m in got} == {os.getpid()}  # what NotifyAccess=main checks
    assert (n.sent, n.failures) == (4, 0)
    n.close()


def test_abstract_namespace_socket(abstract_notify_socket):
    n = Notifier.from_env({"NOTIFY_SOCKET": abstract_notify_socket.address})
    assert n.ready(status="serving on 127.0.0.1:8765")
    assert abstract_notify_socket.recv().data == b"READY=1\nSTATUS=serving on 127.0.0.1:8765"
    n.close()


def test_send_fields_in_order_one_datagram(notify_socket):
    n = Notifier(notify_socket.address)
    assert n.send(STATUS="x", ERRNO=5, BUSERROR="a.b", READY=True)
    assert notify_socket.recv().data == b"STATUS=x\nERRNO=5\nBUSERROR=a.b\nREADY=1"
    assert notify_socket.recv(timeout=0.1) is None  # one datagram, not four
    n.reloading()
    fields = dict(kv.split("=") for kv in notify_socket.recv().data.decode().split("\n"))
    assert fields["RELOADING"] == "1"
    assert abs(int(fields["MONOTONIC_USEC"]) - __import__("time").monotonic_ns() // 1000) < 5e6
    n.extend_timeout(1.5)
    assert notify_socket.recv().data == b"EXTEND_TIMEOUT_USEC=1500000"


def test_status_is_one_bounded_line(notify_socket):
    n = Notifier(notify_socket.address)
    n.status("worker died:\nTraceback ...\n  line 3")
    assert notify_socket.recv().data == b"STATUS=worker died: Traceback ... line 3"
    n.status("x" * 10_000)
    assert len(notify_socket.recv().data) == len("STATUS=") + MAX_STATUS


@pytest.mark.parametrize("fields", [{"ready": 1}, {"STATUS": "a\nREADY=1"}, {}])
def test_malformed_fields_are_programming_errors(fields):
    with pytest.raises(ValueError):
        Notifier("/nonexistent").send(**fields)


def test_unset_is_a_silent_no_op():
    n = Notifier.from_env({})
    assert not n.enabled
    assert n.ready() is False and n.watchdog() is False
    assert (n.sent, n.failures) == (0, 0)
    assert not Notifier.from_env({"NOTIFY_SOCKET": ""}).enabled


def test_unset_environment_removes_the_variable(notify_socket):
    env = {"NOTIFY_SOCKET": notify_socket.address, "OTHER": "1"}
    n = Notifier.from_env(env, unset_environment=True)
    assert env == {"OTHER": "1"}
    assert n.ready()  # the notifier keeps the address it read
    env2 = {"NOTIFY_SOCKET": notify_socket.address}
    Notifier.from_env(env2)
    assert env2 == {"NOTIFY_SOCKET": notify_socket.address}  # default: left alone


def test_send_failure_never_raises_logs_once_and_counts(notify_socket, caplog):
    n = Notifier(notify_socket.address)
    assert n.ready()
    notify_socket.close()
    os.unlink(notify_socket.address)  # the manager went away
    with caplog.at_level(logging.WARNING, logger="tactiled.systemd"):
        results = [n.watchdog() for _ in range(5)]
    assert results == [False] * 5
    assert (n.sent, n.failures) == (1, 5)
    assert len([r for r in caplog.records if "failed" in r.getMessage()]) == 1
    # The manager comes back (daemon-reexec): sending resumes; a new outage is logged anew.
    back = NotifySocket(notify_socket.address)
    assert n.watchdog() and back.recv().data == b"WATCHDOG=1"
    back.close()
    os.unlink(notify_socket.address)
    with caplog.at_level(logging.WARNING, logger="tactiled.systemd"):
        assert n.watchdog() is False
    assert (n.sent, n.failures) == (2, 6)
    assert len([r for r in caplog.records if "failed" in r.getMessage()]) == 2


@pytest.mark.parametrize("value", ["vsock:2:1234", "relative/path"])
def test_unsupported_address_fails_softly(value, caplog):
    n = Notifier.from_env({"NOTIFY_SOCKET": value})
    with caplog.at_level(logging.WARNING, logger="tactiled.systemd"):
        assert n.ready() is False and n.watchdog() is False
    assert n.failures == 2 and len(caplog.records) == 1


# -- watchdog_interval ---------------------------------------------------------------------------

@pytest.mark.parametrize("env, expected", [
    ({}, None),
    ({"WATCHDOG_USEC": "5000000"}, 2.5),
    ({"WATCHDOG_USEC": "2000000", "WATCHDOG_PID": str(os.getpid())}, 1.0),
    ({"WATCHDOG_USEC": "2000000", "WATCHDOG_PID": str(os.getpid() + 1)}, None),  # not ours
    ({"WATCHDOG_USEC": "2000000", "WATCHDOG_PID": "x"}, None),
    ({"WATCHDOG_USEC": "0"}, None),
    ({"WATCHDOG_USEC": str(2**64 - 1)}, None),  # systemd's infinity
    ({"WATCHDOG_USEC": "5s"}, None),
])
def test_watchdog_interval(env, expected):
    assert watchdog_interval(dict(env)) == expected


def test_watchdog_interval_unset_environment():
    env = {"WATCHDOG_USEC": "4000000", "WATCHDOG_PID": str(os.getpid()), "X": "1"}
    assert watchdog_interval(env, unset_environment=True) == 2.0
    assert env == {"X": "1"}


# -- WatchdogGate --------------------------------------------------------------------------------

def test_gate_due_only_after_progress():
    counter = [10]
    gate = WatchdogGate(lambda: counter[0])
    assert not gate.due()  # nothing happened since construction
    counter[0] += 3
    assert gate.due()
    assert not gate.due()  # no new progress since that ping
    assert not gate.due() and gate.stalled_checks == 2
    counter[0] += 1
    assert gate.due() and gate.stalled_checks == 0


def test_watchdog_loop_pings_while_progressing(notify_socket):
    counter = [0]
    n = Notifier(notify_socket.address)

    def drain() -> list[bytes]:
        out = []
        while (m := notify_socket.recv(timeout=0.01)) is not None:
            out.append(m.data)
        return out

    async def scenario() -> tuple[list[bytes], list[bytes]]:
        task = asyncio.create_task(watchdog_loop(n, WatchdogGate(lambda: counter[0]), 0.05))
        for _ in range(15):  # 0.3 s of progress: a ping every interval
            counter[0] += 1
            await asyncio.sleep(0.02)
        progressing = drain()
        await asyncio.sleep(0.3)  # stalled: at most the one ping already under way
        task.cancel()
        return progressing, drain()

    progressing, stalled = asyncio.run(scenario())
    assert set(progressing) == {b"WATCHDOG=1"} and len(progressing) >= 3
    assert len(stalled) <= 1
