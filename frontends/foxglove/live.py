"""Live view in Foxglove: the joint stream served over the Foxglove WebSocket protocol
(``foxglove-sdk``), for ``armbench monitor --foxglove`` and ``armbench emulate --foxglove``.

Topics as in ``capture.mcap`` (CDR, ``ros2msg`` schemas of :mod:`armbench.drivers.model.ros2`):
``/joint_states`` (every reply), ``/joint_states/true`` (the emulator's ground truth beside each
reply, when there is one), ``/tf`` (the joints' link frames), ``/tf_static`` and
``/robot_description`` (the URDF, sent again every :data:`REPEAT_S` seconds so a panel opened later
gets them: the protocol has no latched topics). Times are the loop's, in nanoseconds. The server
listens on loopback unless a host is given; another address needs ``--allow-remote`` (the server
has no authentication and takes any Origin: whoever reaches it can read the stream).
"""

from __future__ import annotations

import contextlib
import ipaddress
import sys
from collections.abc import Iterator
from typing import Any, Final, TextIO

from armbench.drivers.model import ros2
from armbench.drivers.model.errors import ArmbenchError
from armbench.drivers.model.settings import RobotSettings
from armbench.drivers.model.urdf import robot_urdf

__all__ = ["DEFAULT_ENDPOINT", "DEFAULT_HOST", "DEFAULT_PORT", "REPEAT_S", "LiveView",
           "check_bind", "check_live_endpoint", "follow_emulator", "is_loopback", "live_view",
           "parse_endpoint"]

DEFAULT_HOST: Final = "127.0.0.1"
#: Foxglove's default WebSocket port.
DEFAULT_PORT: Final = 8765
#: ``--foxglove`` without a value.
DEFAULT_ENDPOINT: Final = f"{DEFAULT_HOST}:{DEFAULT_PORT}"
#: Seconds between two sends of ``/robot_description`` and ``/tf_static``.
REPEAT_S: Final = 1.0

_TOPICS: Final = {"/joint_states": ros2.JOINT_STATE, "/joint_states/true": ros2.JOINT_STATE,
                  "/tf": ros2.TF_MESSAGE, "/tf_static": ros2.TF_MESSAGE,
                  "/robot_description": ros2.STRING}


def parse_endpoint(text: str, option: str = "--foxglove") -> tuple[str, int]:
    """``HOST:PORT``, ``:PORT`` or ``PORT`` → (host, port); loopback when no host is given."""
    host, sep, port_text = text.rpartition(":")
    if not sep:
        host = ""
    host = host.strip("[]") or DEFAULT_HOST
    try:
        port = int(port_text)
    except ValueError:
        raise ArmbenchError(f"{option}: {text!r} is not HOST:PORT") from None
    if not 0 <= port <= 65535:
        raise ArmbenchError(f"{option}: port {port} is not in 0..65535")
    return host, port


def is_loopback(host: str) -> bool:
    """True for ``localhost`` and loopback addresses (127.0.0.0/8, ::1)."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def check_bind(option: str, host: str, allow_remote: bool, exposes: str) -> str | None:
    """A server of ``option`` may listen on ``host``: loopback always; any other address only
    with ``allow_remote`` (:class:`ArmbenchError` naming the address otherwise), and then the
    returned warning says what it ``exposes`` to the network. None for loopback."""
    if is_loopback(host):
        return None
    if not allow_remote:
        raise ArmbenchError(f"{option}: {host} is not a loopback address; anyone who can reach it "
                            f"could {exposes} (add --allow-remote to mean it)")
    return f"WARNING: {option} serves on {host}: anyone who can reach it can {exposes}"


def check_live_endpoint(endpoint: str, allow_remote: bool) -> str | None:
    """:func:`check_bind` for ``--foxglove HOST:PORT``: what a remote live view exposes."""
    return check_bind("--foxglove", parse_endpoint(endpoint)[0], allow_remote,
                      "read the joint stream and the robot description, without authentication")


class LiveView:
    """A Foxglove WebSocket server publishing the arm's joint stream."""

    def __init__(self, settings: RobotSettings, host: str = DEFAULT_HOST,
                 port: int = DEFAULT_PORT, *, name: str = "armbench") -> None:
        # imported here: emulate and monitor import this module but serve Foxglove only when
        # asked, and the SDK takes a tenth of a second to load
        import foxglove

        self.settings = settings
        self._context = foxglove.Context()
        try:
            self._server: Any = foxglove.start_server(name=name, host=host, port=port,
                                                 context=self._context)
        except Exception as exc:  # the SDK raises its own error types for a busy port
            raise ArmbenchError(f"--foxglove {host}:{port}: cannot serve: {exc}") from exc
        self.host = host
        self._channels: dict[str, Any] = {
            topic: foxglove.Channel(topic, schema=foxglove.Schema(
                name=name_, encoding="ros2msg", data=ros2.SCHEMAS[name_].encode()),
                message_encoding="cdr", context=self._context)
            for topic, name_ in _TOPICS.items()}
        self._js = ros2.JointStateEncoder()
        self._tf = ros2.TfEncoder(ros2.MOVING_PAIRS)
        self._urdf = ros2.encode_string(robot_urdf(settings))
        self._statics = ros2.static_transforms(settings)
        self._static_tf = ros2.TfEncoder(ros2.STATIC_PAIRS)
        self._last_repeat_ns: int | None = None
        self._last_truth_s: float | None = None
        self.sent = 0
        """Joint states published so far."""

    @property
    def port(self) -> int:
        """The port the server listens on (the one chosen when 0 was asked for)."""
        port: int = self._server.port
        return port

    def _log(self, topic: str, data: bytes, t_ns: int) -> None:
        self._channels[topic].log(data, log_time=t_ns)

    def _repeat(self, t_ns: int) -> None:
        if self._last_repeat_ns is not None and t_ns - self._last_repeat_ns < REPEAT_S * 1e9:
            return
        self._last_repeat_ns = t_ns
        self._log("/robot_description", self._urdf, t_ns)
        self._log("/tf_static", self._static_tf.encode(t_ns, self._statics), t_ns)

    def reported(self, t_s: float, q_rad: tuple[float, ...]) -> None:
        """A reply: its joint angles (rad) on ``/joint_states`` and the link frames on ``/tf``."""
        t_ns = max(0, round(t_s * 1e9))
        self._repeat(t_ns)
        self._log("/joint_states", self._js.encode(t_ns, q_rad), t_ns)
        self._log("/tf", self._tf.encode(t_ns, ros2.link_transforms(q_rad, self.settings)), t_ns)
        self.sent += 1

    def truth(self, t_s: float, q_rad: tuple[float, ...]) -> None:
        """The ground truth (rad) beside a reply on ``/joint_states/true``."""
        t_ns = max(0, round(t_s * 1e9))
        self._log("/joint_states/true", self._js.encode(t_ns, q_rad), t_ns)

    def close(self) -> None:
        """Stop the server (idempotent)."""
        server, self._server = self._server, None
        if server is not None:
            server.stop()

    def emulator_sample(self, sample: Any) -> None:
        """A reply the emulator delivered, with its ground truth (``TruthSample``): what the
        firmware reported (its encoders, ``firmware_rad``) and the real angles (``true_rad``)."""
        self.reported(sample.t_s, tuple(sample.firmware_rad))
        self.truth(sample.t_s, tuple(sample.true_rad))

    def driver_state(self, state: Any, truth: Any = None) -> None:
        """A joint state the driver received (``JointState``), and the emulator's newest
        ground truth beside it when there is one (``arm.ground_truth()``)."""
        self.reported(state.t_s, tuple(state.q_rad))
        if truth is not None and truth.t_s != self._last_truth_s:
            self._last_truth_s = truth.t_s
            self.truth(truth.t_s, tuple(truth.true_rad))


@contextlib.contextmanager
def live_view(endpoint: str | None, settings: RobotSettings, *, name: str = "armbench",
              announce: TextIO | None = None,
              allow_remote: bool = False) -> Iterator[LiveView | None]:
    """A :class:`LiveView` on ``endpoint`` (``HOST:PORT``; None: no live view), closed on exit;
    its address is printed to ``announce``. A host other than loopback is refused unless
    ``allow_remote`` (:func:`check_bind`), and warned about on stderr with it."""
    if endpoint is None:
        yield None
        return
    warning = check_live_endpoint(endpoint, allow_remote)
    if warning is not None:
        print(f"armbench {name}: {warning}", file=sys.stderr, flush=True)
    view = LiveView(settings, *parse_endpoint(endpoint), name=name)
    if announce is not None:
        print(f"armbench {name}: Foxglove live view on ws://{view.host}:{view.port}",
              file=announce, flush=True)
    try:
        yield view
    finally:
        view.close()


def follow_emulator(view: LiveView | None, emulator: Any) -> None:
    """Publish every reply the emulator delivers to its host (its UART's delivery hook, which
    also keeps the emulator's ground-truth history)."""
    if view is None:
        return
    uart = emulator.uart
    keep = uart.on_delivered

    def delivered(sample: Any) -> None:
        if keep is not None:
            keep(sample)
        view.emulator_sample(sample)

    uart.on_delivered = delivered
