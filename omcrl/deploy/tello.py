"""The DJI Tello through its real SDK client (``djitellopy``), motion capture through ``motioncapture``, and a
loopback **test double** of the Tello (:class:`FakeTello`) whose drone is the simulated one.

Why ``motioncapture`` for the pose: one maintained client (the Crazyflie team's bindings to libmotioncapture,
used by Crazyswarm2) for OptiTrack — the paper's system — and Vicon, Qualisys and others, with rigid bodies
as position + quaternion; ``natnet`` speaks OptiTrack's NatNet only. Its ``optitrack`` backend is itself a NatNet
client (libmotioncapture's ``MotionCaptureOptitrack``: it queries the server's NatNet version and parses its model
definitions), so the paper's protocol is covered without OptiTrack's SDK (docs/deploy.md, "Pose client").

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

from omcrl.deploy.camera import TELLO
from omcrl.deploy.timing import LAND_FALLBACK_S


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

    def watchdog_address(self) -> tuple[str, int]:
        """Where the watchdog sends ``land`` if the control process dies: the Tello's SDK command address."""
        host, port = self.tello.address
        return str(host), int(port)

    def battery(self) -> float:
        """Charge in % (from the Tello's state packets; no command is sent)."""
        return float(self.tello.get_battery())

    def temperature(self) -> float:
        """Mean of the Tello's low and high temperature readings, °C (state packets)."""
        return float(self.tello.get_temperature())

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

    def land(self, timeout_s: float = LAND_FALLBACK_S) -> None:
        """Land; if the drone does not acknowledge within ``timeout_s`` (one try instead of djitellopy's 3 × 7 s;
        default :data:`omcrl.deploy.timing.LAND_FALLBACK_S`, longer than a normal landing), cut the motors with
        ``emergency`` (logged by the caller through the raised error) rather than leave it flying."""
        self.tello.retry_count, retries = 1, self.tello.retry_count
        try:
            self.tello.send_control_command("land", timeout=max(1, math.ceil(timeout_s)))
            self.tello.is_flying = False
        except Exception as e:
            self.emergency()
            raise RuntimeError(f"land not acknowledged within {timeout_s:g} s ({e}); motors cut (emergency)") from e
        finally:
            self.tello.retry_count = retries

    def emergency(self) -> None:
        """Cut the motors at once (the Tello's ``emergency``; the drone falls): the emergency stop."""
        self.tello.emergency()

    def close(self) -> None:
        """Stop the video reader and end the session (lands first if still flying)."""
        if self._video is not None:
            self._video.stop()
            self._video.reader.stop()
        self.tello.end()
        # djitellopy's __del__ calls end() again, which fails on the already removed drone entry.
        self.tello.__class__ = type("EndedTello", (type(self.tello),), {"__del__": lambda self: None})


class TelloVideo:
    """Video source over djitellopy's ``BackgroundFrameRead``: a frame counts as new when the decoder replaced
    the array, and is stamped with the time it was first seen (the reader gives no timestamps). ``camera``: the
    Tello's intrinsics (:data:`omcrl.deploy.camera.TELLO`)."""

    def __init__(self, reader: Any, camera: Any = None) -> None:

        self.reader = reader
        # The camera the frames come from: the control loop maps them into the simulator's view through it
        # (scaled to the decoded frame's size).
        self.camera = camera if camera is not None else TELLO
        # References, not ids: a freed array's id is reused by the next one, which would look like no new frame.
        self._initial = reader.frame  # the placeholder array before the first decoded frame
        self._last, self._t = self._initial, 0.0
        self._lock = threading.Lock()
        self._stop = threading.Event()
        # A frame's time is when the decoder delivered it, not when the loop first looks: a watcher stamps each
        # new array within POLL_S, so frame_age in the flight log is real and a stalled stream shows at once.
        self._watch = threading.Thread(target=self._stamp, name="tello-video-stamp", daemon=True)
        self._watch.start()

    POLL_S = 0.005

    def _stamp(self) -> None:
        while not self._stop.is_set():
            f = self.reader.frame
            if f is not None and f is not self._initial and f is not self._last:
                with self._lock:
                    self._last, self._t = f, time.monotonic()
            time.sleep(self.POLL_S)

    def read(self) -> tuple[np.ndarray, float] | None:
        with self._lock:
            f, t = self._last, self._t
        if f is None or f is self._initial:
            return None
        return np.asarray(f), t

    def stop(self) -> None:
        self._stop.set()


class MocapPose:
    """Pose source from a motion-capture system through ``motioncapture`` (e.g. OptiTrack at 120 Hz).

    Parameters
    ----------
    system : ``"optitrack"``, ``"vicon"``, ``"qualisys"``, ... (libmotioncapture's names).
    hostname : the mocap server.
    rigid_body : the drone's rigid-body name.
    up : the axis the system streams as up: ``"z"`` (Vicon, Qualisys; OptiTrack Motive with "Up Axis: Z", the
        Crazyswarm setting) or ``"y"`` (Motive's default). See :func:`pose_from_mocap` for the conventions.
    """

    def __init__(self, system: str, hostname: str, rigid_body: str, up: str = "z") -> None:
        import motioncapture

        if up not in ("z", "y"):
            raise ValueError(f"mocap up axis: got {up!r}, expected 'z' or 'y'")
        self.mc = motioncapture.connect(system, {"hostname": hostname})
        self.body, self.up = rigid_body, up
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
            pose = pose_from_mocap(body.position, (q.w, q.x, q.y, q.z), self.up)
            with self._lock:
                self._pose = (pose, time.monotonic())

    def read(self) -> tuple[np.ndarray, float] | None:
        with self._lock:
            return self._pose


# Y-up streaming → Z-up world: a +90° rotation about x (x stays, y_zup = −z_yup, z_zup = y_yup).
_Y_TO_Z = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])


def quat_to_matrix(w: float, x: float, y: float, z: float) -> np.ndarray:
    """Unit quaternion (w, x, y, z) → 3 × 3 rotation matrix (body → world)."""
    n = math.sqrt(w * w + x * x + y * y + z * z)
    if not math.isfinite(n) or n < 1e-9:
        raise ValueError(f"mocap quaternion ({w}, {x}, {y}, {z}) is not a rotation")
    w, x, y, z = w / n, x / n, y / n, z / n
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def pose_from_mocap(position: Any, quaternion: Any, up: str = "z") -> np.ndarray:
    """A mocap rigid body's pose → the loop's pose (6,): x, y, z (m) and roll, pitch, yaw (rad, ZYX) in a right-handed
    Z-up world frame.

    Conventions: the world is the mocap's (its origin and its horizontal axes); x is the direction the drone's
    yaw 0 faces; yaw is counter-clockwise seen from above, in (−π, π]; the rigid body's own axes must be set up
    (in the mocap software) with x forward through the Tello's camera, y to its left and z up — then roll, pitch
    and yaw are those of the env's state. ``up="y"``: a system streaming Y-up (OptiTrack Motive's default:
    x, y up, z) is turned into Z-up by a +90° rotation about x, positions and orientations alike, with the
    body's axes defined Y-up too (forward x, up y).
    """
    p = np.asarray(position, np.float64).reshape(3)
    r = quat_to_matrix(*(float(v) for v in quaternion))
    if up == "y":
        p = _Y_TO_Z @ p
        r = _Y_TO_Z @ r @ _Y_TO_Z.T
    elif up != "z":
        raise ValueError(f"mocap up axis: got {up!r}, expected 'z' or 'y'")
    yaw = math.atan2(r[1, 0], r[0, 0])
    pitch = math.asin(max(-1.0, min(1.0, -r[2, 0])))
    roll = math.atan2(r[2, 1], r[2, 2])
    return np.array([p[0], p[1], p[2], roll, pitch, yaw])


def quat_to_rpy(w: float, x: float, y: float, z: float) -> tuple[float, float, float]:
    """Unit quaternion → (roll, pitch, yaw) in rad, ZYX convention."""
    roll = math.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = math.asin(max(-1.0, min(1.0, 2 * (w * y - z * x))))
    yaw = math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return roll, pitch, yaw


# ---------------------------------------------------------------- the loopback test double
class FakeTello:
    """TEST DOUBLE of a DJI Tello on 127.0.0.1, speaking the SDK's text protocol, flown by a simulated drone.

    It answers SDK commands on ``command_port`` (``command``, ``takeoff``, ``land``, ``emergency``, ``streamon``,
    ``streamoff``, ``port <state> <video>``, ``rc a b c d`` (no reply, as the real drone), anything else ``ok``).
    As a Tello does, it answers ``takeoff`` and ``land`` only when the manoeuvre is done: the simulated drone climbs
    and descends over its ``takeoff_s`` / ``land_s`` (:mod:`omcrl.deploy.timing`; 0 on the drone gives an instant
    fake), while other commands are still received and answered; a ``land`` during the takeoff
    turns it into a landing, one during a landing is answered when it is down, ``emergency`` drops the drone at
    once. Every command is recorded in ``received`` and, with its arrival time (``time.monotonic()``), in
    ``log``. It sends state
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
        acknowledge_land: bool = True,
        battery: int = 90,
        auto_land_s: float = 15.0,
    ) -> None:
        self.drone, self.host = drone, host
        self.acknowledge_land = bool(acknowledge_land)  # False: a drone that never answers `land` (tests)
        self.battery = int(battery)  # the charge its state packets report, %
        # Like the Tello's firmware: land by itself after this long without any command while flying.
        self.auto_land_s, self._last_cmd = float(auto_land_s), time.monotonic()
        self.auto_landed = False
        self.state_port, self.video_port = state_port, video_port
        self.speed_at_100, self.yaw_at_100 = speed_at_100, yaw_rate_at_100
        self.state_hz, self.video_fps = state_hz, video_fps
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind((host, command_port))
        self.sock.settimeout(0.2)
        self.command_port = self.sock.getsockname()[1]
        self.received: list[str] = []
        self.log: list[tuple[float, str]] = []  # (arrival time, command), as the drone receives them
        self._send_lock = threading.Lock()
        self._landing: threading.Thread | None = None
        self._land_waiters: list[Any] = []
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
                if self.drone.flying and time.monotonic() - self._last_cmd > self.auto_land_s:
                    self.auto_landed = True
                    self._land(None)
                continue
            cmd = data.decode("utf-8", "replace").strip()
            self._last_cmd = time.monotonic()
            self.log.append((self._last_cmd, cmd))
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
                # Answered when the drone is up (or not at all when a landing cut the climb short).
                threading.Thread(target=self._takeoff, args=(addr,), daemon=True).start()
                continue
            elif cmd == "land":
                if not self.acknowledge_land:
                    continue  # no reply, and the drone keeps flying
                self._land(addr)
                continue
            elif cmd == "emergency":
                self.drone.emergency()
            elif cmd.startswith("port "):
                self.video_port = int(cmd.split()[2])
            elif cmd == "streamon":
                self._video_on.set()
            elif cmd == "streamoff":
                self._video_on.clear()
            self._reply(reply, addr)

    def _reply(self, text: str, addr: Any) -> None:
        with self._send_lock:
            try:
                self.sock.sendto(text.encode(), addr)
            except OSError:  # closed meanwhile
                pass

    def _takeoff(self, addr: Any) -> None:
        self.drone.takeoff()
        if self.drone.flying:
            self._reply("ok", addr)

    def _land(self, addr: Any) -> None:
        """Start the landing (once) and answer every ``land`` received until it is down, when it is down."""
        with self._send_lock:
            self._land_waiters.append(addr)
            if self._landing is not None:
                return
            self._landing = threading.Thread(target=self._descend, daemon=True)
        self._landing.start()

    def _descend(self) -> None:
        self.drone.land()
        with self._send_lock:
            waiters, self._land_waiters, self._landing = self._land_waiters, [], None
        for addr in dict.fromkeys(waiters):
            if addr is not None:  # None: the firmware's own auto-land, which nobody asked for
                self._reply("ok", addr)

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
                "bat": self.battery,
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
