"""A watchdog that lands the drone when the control loop dies or freezes, in any phase of the flight.

:class:`ControlLoop` starts it as a separate process (``python watchdog.py HOST PORT TIMEOUT_S LAND_ACK_S``) when
the drone gives a command address (``drone.watchdog_address()``, the Tello's SDK port). The loop beats on the
watchdog's standard input: one byte naming the flight phase (``t`` taking off, ``.`` in flight, ``l`` landing)
every tick, and from a thread of its own while it waits on the drone's ``takeoff`` or ``land`` (a Tello answers them
only when the manoeuvre is done, seconds later); ``x`` when it has landed. A thread dies with its process and stops
with it, so the beats stop when the loop is killed (``kill -9``: the kernel closes the pipe) or frozen (``SIGSTOP``,
a hung interpreter).

When the beats stop for ``timeout_s`` or the pipe closes without ``x``, the watchdog sends the Tello SDK's ``land``
from its own UDP socket and waits up to ``land_ack_s`` for an answer — a Tello answers ``land`` when it is down, and
one already landing answers when it gets there — and only then sends ``emergency`` (motors cut): never while a
landing goes on normally. ``land_ack_s`` is :data:`omcrl.deploy.timing.LAND_FALLBACK_S`. Independently of all this
the Tello lands by itself after about 15 s without any command (its firmware's safety); the kit's fake Tello does the
same (``FakeTello(auto_land_s=15)``), so tests can tell the watchdog's landing from the drone's own.

Standard library only, so it starts in milliseconds.
"""

from __future__ import annotations

import os
import select
import socket
import sys
import time

PHASES = {b"t": "takeoff", b".": "cruise", b"l": "landing"}


def watch(
    host: str, port: int, timeout_s: float = 0.5, land_ack_s: float = 8.0, stdin: int | None = None
) -> tuple[str, str]:
    """Run until the loop says it landed or dies; returns (what the watchdog did, the phase it was in):
    ``("released", phase)``, ``("land", phase)`` (acknowledged) or ``("emergency", phase)`` (not acknowledged
    within ``land_ack_s``)."""
    fd = sys.stdin.fileno() if stdin is None else stdin
    last = time.monotonic()
    phase = "takeoff"
    while True:
        ready, _, _ = select.select([fd], [], [], 0.02)
        if ready:
            data = os.read(fd, 4096)
            if not data:
                break  # the loop's process is gone
            if b"x" in data:
                return "released", phase
            phase = PHASES.get(data[-1:], phase)
            last = time.monotonic()
        elif time.monotonic() - last > timeout_s:
            break  # the loop hangs
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        sock.sendto(b"land", (host, port))
        deadline = time.monotonic() + land_ack_s
        while (left := deadline - time.monotonic()) > 0:
            sock.settimeout(left)
            try:
                reply, _ = sock.recvfrom(1024)
            except OSError:
                break
            if reply.strip():  # "ok" when down; any answer means the drone heard it and acts on it
                return "land", phase
        sock.sendto(b"emergency", (host, port))
        return "emergency", phase
    finally:
        sock.close()


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    host, port = args[0], int(args[1])
    timeout_s = float(args[2]) if len(args) > 2 else 0.5
    land_ack_s = float(args[3]) if len(args) > 3 else 8.0
    what, phase = watch(host, port, timeout_s, land_ack_s)
    print(f"watchdog: {what} (loop in its {phase} phase)", file=sys.stderr, flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
