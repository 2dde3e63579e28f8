"""The soak's child processes: three simulated fingers (``tactiled simulate --pty``, which
also report the seqs they skipped, dropped or overflowed) and the WebSocket subscribers, healthy
and never-reading, driven over stdin and stdout lines by :mod:`tactiled_bench.reliability`.
"""

from __future__ import annotations

import asyncio
import json
import os
import re
import signal
import subprocess
import sys
from pathlib import Path
from typing import Any


FINGERS = ("thumb", "index", "middle")


_SUMMARY = re.compile(r"sent (\d+) frame\(s\), dropped (\d+) \(device full\), skipped (\d+)")
_RUNS = re.compile(r"^seq runs: (\{.*\})$", re.MULTILINE)

#: A simulator: ``tactiled simulate`` run through :func:`simulator_main` (arguments follow).
_SIMULATOR = ("import sys; from tactiled_bench.soak_children import simulator_main; "
              "sys.exit(simulator_main(sys.argv[1:]))")
#: The subscribers: :func:`subscribers_main` with the port and counts as arguments.
_SUBSCRIBERS = ("import sys; from tactiled_bench.soak_children import subscribers_main; "
                "sys.exit(subscribers_main(*sys.argv[1:]))")


# -- the simulators -------------------------------------------------------------------------------


def simulator_main(argv: list[str]) -> int:
    """``tactiled simulate ARGV`` (the real command, in this process), which also prints, at
    exit, ``seq runs: {"skipped": [[seq, n], ...], "dropped": [...], "overflowed": [...]}``
    on stderr, so the soak can tell which of the frames missing at the daemon's decoder were
    ever offered to the device (the seq of a frame is its tick index):

    * ``skipped``: behind schedule by more than ``MAX_LAG_S`` (starved), never generated;
    * ``dropped``: refused because the device was full: the last write left bytes pending
      (``EAGAIN``), i.e. the reader had not emptied the pty in time;
    * ``overflowed``: refused by the writer's own limit with the device not full: after a
      starved spell the command queues a catch-up batch of up to ``MAX_BATCH`` (32) frames
      before writing any, and 32 frames of 152 bytes exceed ``PENDING_LIMIT`` (4096), so the
      frames past the 26th of such a batch are dropped without the device being tried.

    ``dropped + overflowed`` is the command's own "dropped (device full)" count and
    ``skipped`` its "skipped"; only the positions and the split are added here."""
    from tactiled_bench.scenes import register_bench_scenes
    from tactiled.cli import main as cli_main
    from tactiled.commands import simulate

    _exit_with_parent()
    register_bench_scenes()  # --scene busy
    runs: dict[str, list[list[int]]] = {"skipped": [], "dropped": [], "overflowed": []}
    tick = [0]  # seq of the next frame handed to the writer

    def add(kind: str, seq: int, n: int) -> None:
        r = runs[kind]
        if r and r[-1][0] + r[-1][1] == seq:
            r[-1][1] += n
        else:
            r.append([seq, n])

    class Schedule(simulate.FrameSchedule):
        def take(self, now: float, limit: int) -> tuple[int, int]:
            first = self.sent
            skip, send = super().take(now, limit)
            if skip:
                add("skipped", first, skip)  # the command calls sim.skip(skip): seqs jump
            tick[0] = first + skip
            return skip, send

    class Writer(simulate.FrameWriter):
        full = False  # the last flush left bytes pending: the device refused them

        def send(self, data: bytes) -> None:
            dropped = self.dropped
            super().send(data)
            if self.dropped != dropped:
                add("dropped" if self.full else "overflowed", tick[0], 1)
            tick[0] += 1

        def flush(self) -> None:
            super().flush()
            self.full = bool(self.pending)

    simulate.FrameSchedule = Schedule  # type: ignore[misc]  # looked up by _serve at run time
    simulate.FrameWriter = Writer  # type: ignore[misc]
    code = cli_main(["simulate", *argv])
    print("seq runs: " + json.dumps(runs), file=sys.stderr, flush=True)
    return code


def _exit_with_parent() -> None:
    """Be sent SIGTERM when the soak process dies (killed by a test's timeout, say), so no
    simulator outlives it (Linux ``prctl(PR_SET_PDEATHSIG)``; elsewhere nothing)."""
    try:
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(1, signal.SIGTERM, 0, 0, 0)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        return
    if os.getppid() == 1:  # the parent is already gone
        os.kill(os.getpid(), signal.SIGTERM)


def start_simulators(tmp: Path, rate: float, scene: str) -> list[tuple[subprocess.Popen, Path]]:
    sims = []
    for i, _ in enumerate(FINGERS):
        log = tmp / f"sim{i}.log"
        with open(log, "w") as err:
            p = subprocess.Popen(
                [sys.executable, "-c", _SIMULATOR, "--pty", "--link", str(tmp / f"tty{i}"),
                 "--scene", scene, "--rate", repr(rate), "--sensor-id", str(i + 1),
                 "--seed", str(i + 1)],
                stdout=subprocess.PIPE, stderr=err, text=True)
        sims.append((p, log))
    for i, (p, log) in enumerate(sims):
        line = p.stdout.readline() if p.stdout else ""
        if not line.startswith("pty:"):
            stop_simulators(sims)
            raise RuntimeError(f"simulator {i} did not start: {line!r} {log.read_text()}")
    return sims


def stop_simulators(sims: list[tuple[subprocess.Popen, Path]]) -> list[dict[str, Any]]:
    for p, _ in sims:
        if p.poll() is None:
            p.send_signal(signal.SIGTERM)
    out = []
    for p, log in sims:
        try:
            p.wait(timeout=10)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()
        if p.stdout:
            p.stdout.close()
        text = log.read_text()
        m, runs = _SUMMARY.search(text), _RUNS.search(text)
        out.append({"sent": int(m[1]), "dropped": int(m[2]), "skipped": int(m[3]),
                    "runs": json.loads(runs[1]) if runs else None} if m else {})
    return out


def in_range(runs: list[list[int]] | None, lo: int, hi: int) -> int:
    """How many seqs of ``runs`` ([first, count] pairs) fall within ``lo..hi`` inclusive."""
    return sum(max(0, min(hi, s + n - 1) - max(lo, s) + 1) for s, n in runs or ())


# -- the subscribers (a child process) ------------------------------------------------------------


def subscribers_main(port: str, healthy: str, stalled: str, max_rate: str) -> int:
    """Subscribers of ``ws://127.0.0.1:PORT/v1/stream``, driven through stdin / stdout lines.

    ``healthy`` readers (one selector thread) and ``stalled`` never-reading subscribers, all
    asking for the estimates of every sensor at ``max_rate``; a never-reading one the server
    has closed reconnects (within 0.2 s) and stalls again.  Prints ``ready`` once all are
    connected; on ``stop``: stops reconnecting, sends every reader an ``unsubscribe``, waits
    for the confirmations (the server's counters are then final) and prints one JSON line
    (per reader: local port, estimates received, closed; the never-reading ones'
    connections); on ``exit`` (or end of input): closes everything.
    """
    from tactiled_bench.websocket_fanout import Readers, Restaller, Staller

    sub = json.dumps({"type": "subscribe", "streams": ["estimates"],
                      "max_rate": float(max_rate)}).encode()
    stallers = [Staller(int(port), sub) for _ in range(int(stalled))]
    readers = Readers()
    restaller = Restaller(stallers, name="soak-stallers")
    try:
        for s in stallers:
            s.connect()
        for _ in range(int(healthy)):
            readers.add(int(port), sub)
        readers.start()
        restaller.start()
        print("ready", flush=True)
        for line in sys.stdin:
            command = line.strip()
            if command == "exit":
                break
            if command != "stop":
                continue
            restaller.stop()
            # A reader without its confirmation is reported, and counts as failed.
            readers.unsubscribe_all(30.0)
            print(json.dumps({
                "readers": [{"port": c.port, "received": c.total, "closed": c.closed,
                             "unsubscribed": c.unsubscribed} for c in readers.clients],
                "stalled_connects": [s.connects for s in stallers]}), flush=True)
    finally:
        restaller.stop()
        for s in stallers:
            s.close()
        readers.stop()
    return 0


class Subscribers:
    """The subscriber child process, seen from the soak (asyncio)."""

    def __init__(self, proc: asyncio.subprocess.Process) -> None:
        self.proc = proc

    @classmethod
    async def start(cls, port: int, healthy: int, stalled: int,
                    max_rate: float) -> Subscribers:
        proc = await asyncio.create_subprocess_exec(
            sys.executable, "-c", _SUBSCRIBERS, str(port), str(healthy), str(stalled),
            repr(max_rate), stdin=asyncio.subprocess.PIPE, stdout=asyncio.subprocess.PIPE)
        self = cls(proc)
        line = await self._line(60.0)
        if line != "ready":
            await self.close()
            raise RuntimeError(f"the subscribers did not start (printed {line!r})")
        return self

    async def _line(self, timeout: float) -> str:
        assert self.proc.stdout is not None
        return (await asyncio.wait_for(self.proc.stdout.readline(), timeout)).decode().strip()

    async def stop(self) -> dict[str, Any]:
        """Unsubscribe the readers (flushing the server's counters); their tallies."""
        assert self.proc.stdin is not None
        self.proc.stdin.write(b"stop\n")
        await self.proc.stdin.drain()
        return json.loads(await self._line(60.0))

    async def close(self) -> None:
        if self.proc.returncode is None:
            try:
                assert self.proc.stdin is not None
                self.proc.stdin.write(b"exit\n")
                await self.proc.stdin.drain()
                self.proc.stdin.close()
                await asyncio.wait_for(self.proc.wait(), 10)
            except (OSError, TimeoutError):
                self.proc.kill()
                await self.proc.wait()
