"""A watchdog that lands the drone when the control loop dies, however it dies (``kill -9`` included).

:class:`ControlLoop` starts it as a separate process (``python -m omcrl.deploy.watchdog HOST PORT``) when the
drone gives a command address (``drone.watchdog_address()``, the Tello's SDK port). The loop writes one byte to the
watchdog's standard input every tick and ``x`` when it has landed. The watchdog sends the Tello SDK's ``land``
from its own UDP socket when the heartbeat stops for ``timeout_s`` or the pipe closes without ``x`` (the loop's
process ended: its end of the pipe is closed by the kernel, even after ``kill -9``), then ``emergency`` when ``land``
is not acknowledged within ``ack_s``. Independently of all this the Tello lands by itself after about 15 s without
any command (its firmware's safety); the kit's fake Tello does the same (``FakeTello(auto_land_s=15)``), so tests
can tell the watchdog's landing (well under a second) from the drone's own.
"""

from __future__ import annotations

import os
import select
import socket
import sys
import time


def watch(host: str, port: int, timeout_s: float = 0.5, ack_s: float = 1.0, stdin: int | None = None) -> str:
    """Run until the loop says it landed (returns ``"released"``) or dies (sends ``land``; returns what it did)."""
    fd = sys.stdin.fileno() if stdin is None else stdin
    last = time.monotonic()
    while True:
        ready, _, _ = select.select([fd], [], [], 0.05)
        if ready:
            data = os.read(fd, 4096)
            if not data:
                break  # the loop's process is gone
            if b"x" in data:
                return "released"
            last = time.monotonic()
        elif time.monotonic() - last > timeout_s:
            break  # the loop hangs
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.settimeout(ack_s)
    try:
        sock.sendto(b"land", (host, port))
        try:
            reply, _ = sock.recvfrom(1024)
            if b"ok" in reply.lower():
                return "land"
        except OSError:
            pass
        sock.sendto(b"emergency", (host, port))
        return "emergency"
    finally:
        sock.close()


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    host, port = args[0], int(args[1])
    timeout_s = float(args[2]) if len(args) > 2 else 0.5
    what = watch(host, port, timeout_s)
    print(f"watchdog: {what}", file=sys.stderr, flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
