"""The DJI Tello through its real SDK client (``djitellopy``), motion capture through ``motioncapture``, and a
loopback **test double** of the Tello (:class:`FakeTello`) whose drone is the simulated one.

Why ``motioncapture`` for the pose: one maintained client (the Crazyflie team's bindings to libmotioncapture,
used by Crazyswarm2) for OptiTrack — the paper's system — and Vicon, Qualisys and others, with rigid bodies
as position + quaternion; ``natnet`` speaks OptiTrack's NatNet only.

Tello conventions: ``send_rc_control(left_right, forward_backward, up_down, yaw)`` takes integers in
[−100, 100]; yaw > 0 turns clockwise (seen from above), so ω_z (counter-clockwise) is negated, and left is
−left_right. How fast 100 is depends on the drone's speed setting: ``speed_at_100`` (m/s) and
``yaw_rate_at_100`` (rad/s) calibrate it.
"""

from __future__ import annotations

import math
import socket
import threading
import time
from typing import Any

import numpy as np


class TelloDrone:
    """The :class:`~omcrl.deploy.loop.Drone` interface over a real ``djitellopy.Tello``.

    Parameters
    ----------
    host : the Tello's address (192.168.10.1 on its own Wi-Fi).
    command_port : its SDK command port (8889). The loopback test double listens on another port because
        djitellopy binds the client's reply socket to 8889 on every address.
    speed_at_100, yaw_rate_at_100 : m/s and rad/s that an rc value of 100 gives (calibrate on the drone).
    verbose : djitellopy's INFO log of every command.
    video_port : where the video stream should arrive (11111, the drone's default; another port is asked for
        with the SDK's ``port`` command). djitellopy's video reader keeps its port until a frame arrives after
        ``close``, so a second session in the same process should use another port.
    """

    def __init__(
        self,
        host: str = "192.168.10.1",
        command_port: int = 8889,
        speed_at_100: float = 1.0,
        yaw_rate_at_100: float = math.radians(100.0),
        verbose: bool = False,
        video_port: int = 11111,
    ) -> None:
        import logging

        from djitellopy import Tello

        # djitellopy logs every command at INFO (10 lines a second in flight); the flight log has them all.
        Tello.LOGGER.setLevel(logging.INFO if verbose else logging.WARNING)
        self.tello = Tello(host=host, vs_udp=int(video_port))
        if command_port != Tello.CONTROL_UDP_PORT:
            self.tello.address = (host, int(command_port))
        self.video_port = int(video_port)
        self.speed_at_100, self.yaw_at_100 = float(speed_at_100), float(yaw_rate_at_100)
        self._video: TelloVideo | None = None

    def connect(self, video: bool = True) -> None:
        """Enter SDK mode (waits for the first state packet) and start the video stream."""
        self.tello.connect()
        if self.video_port != 11111:
            # SDK 2.0's "port" command: the drone sends its video to this port (djitellopy's change_vs_udp).
            self.tello.change_vs_udp(self.video_port)
        if video:
            self.tello.streamon()

    def video(self) -> TelloVideo:
        if self._video is None:
            self._video = TelloVideo(self.tello.get_frame_read())
        return self._video

    def takeoff(self) -> None:
        self.tello.takeoff()

    def rc(self, vx: float, vy: float, wz: float) -> tuple[int, int, int, int]:
        """Body-frame velocities → the Tello's rc integers (left_right, forward_backward, up_down, yaw)."""

        def pct(v: float, full: float) -> int:
            # min(100.0, nan) is 100.0: a NaN would become full stick. Nothing non-finite reaches the motors.
            if not math.isfinite(v):
                raise ValueError(f"rc: non-finite velocity {v!r}; refusing to send it to the drone")
            return round(max(-100.0, min(100.0, 100.0 * v / full)))

        return pct(-vy, self.speed_at_100), pct(vx, self.speed_at_100), 0, pct(-wz, self.yaw_at_100)

    def send_velocity(self, vx: float, vy: float, wz: float) -> None:
        self.tello.send_rc_control(*self.rc(vx, vy, wz))

    def land(self) -> None:
        self.tello.land()

    def close(self) -> None:
        """Stop the video reader and end the session (lands first if still flying)."""
        if self._video is not None:
            self._video.reader.stop()
        self.tello.end()
        # djitellopy's __del__ calls end() again, which fails on the already removed drone entry.
        self.tello.__class__ = type("EndedTello", (type(self.tello),), {"__del__": lambda self: None})


class TelloVideo:
    """Video source over djitellopy's ``BackgroundFrameRead``: a frame counts as new when the decoder replaced
    the array, and is stamped with the time it was first seen (the reader gives no timestamps)."""

    def __init__(self, reader: Any) -> None:
        self.reader = reader
        # References, not ids: a freed array's id is reused by the next one, which would look like no new frame.
        self._initial = reader.frame  # the placeholder array before the first decoded frame
        self._last, self._t = self._initial, 0.0

    def read(self) -> tuple[np.ndarray, float] | None:
        f = self.reader.frame
        if f is None or f is self._initial:
            return None
        if f is not self._last:
            self._last, self._t = f, time.monotonic()
        return np.asarray(f), self._t


class MocapPose:
    """Pose source from a motion-capture system through ``motioncapture`` (e.g. OptiTrack at 120 Hz).

    Parameters
    ----------
    system : ``"optitrack"``, ``"vicon"``, ``"qualisys"``, ... (libmotioncapture's names).
    hostname : the mocap server.
    rigid_body : the drone's rigid-body name.
    """

    def __init__(self, system: str, hostname: str, rigid_body: str) -> None:
        import motioncapture

        self.mc = motioncapture.connect(system, {"hostname": hostname})
        self.body = rigid_body
        self._pose: tuple[np.ndarray, float] | None = None
        self._lock = threading.Lock()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while True:
            self.mc.waitForNextFrame()
            body = self.mc.rigidBodies.get(self.body)
            if body is None:
                continue
            q = body.rotation  # w, x, y, z
            pose = np.array([*body.position, *quat_to_rpy(q.w, q.x, q.y, q.z)])
            with self._lock:
                self._pose = (pose, time.monotonic())

    def read(self) -> tuple[np.ndarray, float] | None:
        with self._lock:
            return self._pose


def quat_to_rpy(w: float, x: float, y: float, z: float) -> tuple[float, float, float]:
    """Unit quaternion → (roll, pitch, yaw) in rad, ZYX convention."""
    roll = math.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = math.asin(max(-1.0, min(1.0, 2 * (w * y - z * x))))
    yaw = math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return roll, pitch, yaw


# ---------------------------------------------------------------- the loopback test double
class FakeTello:
    """TEST DOUBLE of a DJI Tello on 127.0.0.1, speaking the SDK's text protocol, flown by a simulated drone.

    It answers SDK commands on ``command_port`` (``command``, ``takeoff``, ``land``, ``streamon``, ``streamoff``,
    ``port <state> <video>``, ``rc a b c d`` (no reply, as the real drone), anything else ``ok``), sends state
    packets to the client's port 8890 at ``state_hz`` and, after ``streamon``, the simulated camera as an H.264
    stream (PyAV, libx264) in 1,460-byte UDP datagrams to the client's video port (11111 unless the ``port``
    command changed it), as the drone does. :meth:`cut_video` stops
    the video (the loop must land). Only for tests and demos on a machine without a drone.
    """

    def __init__(
        self,
        drone: Any,
        host: str = "127.0.0.1",
        command_port: int = 0,
        state_port: int = 8890,
        video_port: int = 11111,
        speed_at_100: float = 1.0,
        yaw_rate_at_100: float = math.radians(100.0),
        state_hz: float = 10.0,
        video_fps: float = 15.0,
    ) -> None:
        self.drone, self.host = drone, host
        self.state_port, self.video_port = state_port, video_port
        self.speed_at_100, self.yaw_at_100 = speed_at_100, yaw_rate_at_100
        self.state_hz, self.video_fps = state_hz, video_fps
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind((host, command_port))
        self.sock.settimeout(0.2)
        self.command_port = self.sock.getsockname()[1]
        self.received: list[str] = []
        self._stop = threading.Event()
        self._video_on = threading.Event()
        self._video_cut = threading.Event()
        self._threads = [
            threading.Thread(target=self._serve, daemon=True),
            threading.Thread(target=self._state, daemon=True),
            threading.Thread(target=self._video, daemon=True),
        ]
        for t in self._threads:
            t.start()

    def _serve(self) -> None:
        while not self._stop.is_set():
            try:
                data, addr = self.sock.recvfrom(1024)
            except (TimeoutError, OSError):
                continue
            cmd = data.decode("utf-8", "replace").strip()
            self.received.append(cmd)
            reply = "ok"
            if cmd.startswith("rc "):
                a, b, _, d = (int(v) for v in cmd.split()[1:5])
                vx = b / 100.0 * self.speed_at_100
                vy = -a / 100.0 * self.speed_at_100
                wz = -d / 100.0 * self.yaw_at_100
                self.drone.send_velocity(vx, vy, wz)
                continue  # rc gets no reply
            if cmd == "takeoff":
                self.drone.takeoff()
            elif cmd == "land":
                self.drone.land()
            elif cmd.startswith("port "):
                self.video_port = int(cmd.split()[2])
            elif cmd == "streamon":
                self._video_on.set()
            elif cmd == "streamoff":
                self._video_on.clear()
            self.sock.sendto(reply.encode(), addr)

    def _state(self) -> None:
        out = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        out.bind((self.host, 0))
        while not self._stop.is_set():
            p = self.drone.pose
            fields = {
                "pitch": int(math.degrees(p[4])),
                "roll": int(math.degrees(p[3])),
                "yaw": int(math.degrees(p[5])),
                "vgx": 0,
                "vgy": 0,
                "vgz": 0,
                "templ": 60,
                "temph": 62,
                "tof": int(100 * p[2]),
                "h": int(100 * p[2]),
                "bat": 90,
                "baro": 0.0,
                "time": 0,
                "agx": 0.0,
                "agy": 0.0,
                "agz": -1000.0,
            }
            msg = ";".join(f"{k}:{v}" for k, v in fields.items()) + ";\r\n"
            out.sendto(msg.encode(), (self.host, self.state_port))
            time.sleep(1.0 / self.state_hz)
        out.close()

    def _video(self) -> None:
        import av

        out = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        out.bind((self.host, 0))
        codec = None
        while not self._stop.is_set():
            if not self._video_on.is_set() or self._video_cut.is_set():
                time.sleep(0.02)
                continue
            frame, _ = self.drone.latest_frame()
            h, w = frame.shape[:2]
            if codec is None:
                codec = av.CodecContext.create("libx264", "w")
                codec.width, codec.height, codec.pix_fmt = w - w % 2, h - h % 2, "yuv420p"
                codec.framerate = int(self.video_fps)
                # Short GOP with in-band headers: a client that joins late decodes within a second, like the Tello.
                x264 = "keyint=15:repeat-headers=1"
                codec.options = {"preset": "ultrafast", "tune": "zerolatency", "x264-params": x264}
            vf = av.VideoFrame.from_ndarray(np.ascontiguousarray(frame[: codec.height, : codec.width]), format="rgb24")
            for packet in codec.encode(vf):
                data = bytes(packet)
                for i in range(0, len(data), 1460):
                    out.sendto(data[i : i + 1460], (self.host, self.video_port))
            time.sleep(1.0 / self.video_fps)
        out.close()

    def cut_video(self) -> None:
        """Stop sending video (as when the Wi-Fi link drops the stream)."""
        self._video_cut.set()

    def close(self) -> None:
        self._stop.set()
        for t in self._threads:
            t.join(timeout=1.0)
        self.sock.close()
