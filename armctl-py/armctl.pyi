"""Drive the arm controller (the board or sim-host) from Python.

    with armctl.connect("127.0.0.1:8510") as arm:
        arm.run(times, positions)

Every call forwards to the armctl Rust library (the same client as the `armctl` tool).
Waits release the GIL. Motion calls stop what they started: a KeyboardInterrupt or any
error in run(), run_file(), RunHandle.wait() or go_home(), and any exception leaving a
`with` block while a run or RETURN of this connection may be under way, send STOPPED
(resent every 100 ms until ACKed, 10 copies at most; a second Ctrl-C ends the wait; not
ACKed: a RuntimeWarning) before the exception propagates. A run that fails by itself
(a refused upload, a stall, a lost link) sends STOPPED from its own thread even when
nobody waits for it (wait=False).

SIGTERM and SIGHUP (systemd, `docker stop`, `kill`, a closed terminal): from connect()
on, armctl's handler sends STOPPED to every controller with a run or RETURN of this
process under way (resent until ACKed; a second signal ends the wait), prints
`armctl: SIGTERM: STOPPED sent, ...` on stderr, then the process dies of the signal as
it would have without armctl (no exception, no `finally`: exit status -15 / 143). It is
installed only where the handler is still SIG_DFL, and only from the main thread: a
handler of your own, set before or after connect(), is kept; raise from it (e.g.
sys.exit) and the motion call or `with` block sends STOPPED as for any exception.
"""

from os import PathLike
from typing import (
    Any, Dict, Iterator, List, Literal, Optional, Sequence, Tuple, TypedDict, Union, overload,
)

import numpy as np
import numpy.typing as npt

PORT: int
"""The controller's UDP port, 8510."""

_Path = Union[str, PathLike]
_Units = Literal["steps", "deg", "rad"]

class Flags(TypedDict):
    reports_on: bool
    drivers_enabled: bool
    serial_open: bool
    pin0_high: bool
    pin1_high: bool
    underrun: bool
    """The last run ended because the buffer ran dry."""
    pwm_active: bool
    stopped_by_host: bool
    """The last run ended by STOPPED."""

class Status(TypedDict):
    version: Tuple[int, int, int]
    joints: int
    state: str
    """'NEW', 'PENDING', 'RUNNING' or 'STOPPED'."""
    flags: Flags
    buffered: int
    expected: int
    received: int
    executed: int
    capacity: int
    upload_period_us: int
    pwm_timer_clock_hz: int
    max_step_rate_hz: int
    window: int
    """Datagrams the controller takes back to back (0: an older controller, assume 8)."""
    step_budget_hz: int
    """Steps per second of all joints together (0: an older controller)."""
    more_flags: MoreFlags
    enabled: Optional[Enabled]
    """Each driver's ENABLE (None: an older controller, which reports only
    flags['drivers_enabled'], "any")."""
    stop_cause: Optional[str]
    """What ended the last run (issue 31): 'COMPLETE', 'STOPPED', 'ESTOP_INPUT', 'UNDERRUN', 'FAULT' (later 'LIMIT_SWITCH', 'HOLD'); None from an older controller."""
    stopped_by: Optional[str]
    """From `Arm.status()`: the STOPPED's sender ('127.0.0.2:40001') when stop_cause is 'STOPPED' and the controller tells; else None."""

class JointLimits(TypedDict):
    min: int
    """Lowest position, steps (-2147483648: none)."""
    max: int
    """Highest position, steps (2147483647: none)."""
    max_rate_hz: int
    """Most steps per second (0: the controller's own limit only)."""

class JointDescription(TypedDict):
    name: str
    """The joint's name ('' when none)."""
    unit: str
    """'steps', 'deg', 'rad' or 'mm': the units hosts show it in."""
    zero_offset: int
    """Step position of the unit's 0."""
    scale: float
    """Steps per radian (deg, rad), per mm (mm) or per step; 0.0: not described."""
    described: bool
    """Whether a description is kept (a scale given)."""

class Enabled(TypedDict):
    joints: List[bool]
    """One per joint in use: True holding, False limp."""
    gripper: bool

class MoreFlags(TypedDict):
    upload_dropped: bool
    estop_open: bool
    estop_latched: bool

class Location(TypedDict):
    positions: npt.NDArray[np.int32]
    """One position per joint in use, in steps."""
    state: str

class Progress(TypedDict):
    total: int
    sent: int
    acked: int
    executed: int
    state: str
    done: bool

class RunReport(TypedDict):
    points: int
    frames: int
    window: int
    datagrams_sent: int
    retransmissions: int
    upload_time: float
    total_time: float
    final_status: Optional[Status]
    final_positions: Optional[npt.NDArray[np.int32]]

class ArmctlError(Exception):
    """Base class of every error of this module."""

class RefusedError(ArmctlError):
    """The controller refused a command; it did nothing."""

    status: str
    """The status name, e.g. 'BAD_STATE', 'NOT_OWNER', 'INVALID_CONFIG'."""
    command: str
    """The command refused, e.g. 'NEW'."""
    state: str
    """The controller's state when it refused."""

class NoReplyError(ArmctlError):
    """No ACK (or report) after every retry, or nothing listening (a refused loopback port): wrong address, controller off."""

class RunEndedError(ArmctlError):
    """A run ended before every point ran."""

    reason: str
    """'stopped', 'estop_input', 'fault', 'underrun', 'starved' or 'unknown'."""
    stopped_by: Optional[str]
    """For 'stopped': the STOPPED's sender ('127.0.0.2:40001') if the controller said (issue 31)."""
    controlled: bool
    """For 'underrun': the controller slowed along what it held, within the accelerations, and stopped on the last point it had (issue 32); False: a dead stop at speed, or an older controller."""
    executed: Optional[int]
    received: Optional[int]
    """Points the controller had received: more than `executed` means points were still buffered."""
    total: int

class StalledError(ArmctlError):
    """An upload or run made no progress for too long."""

class TrajectoryError(ArmctlError):
    """A trajectory the controller cannot take (shape, limits, step rate, file)."""

class RunHandle:
    """A run started with wait=False."""

    @property
    def progress(self) -> Progress: ...
    @property
    def done(self) -> bool: ...
    def wait(self, timeout: Optional[float] = None) -> RunReport:
        """Waits for the end (TimeoutError after `timeout` s; the run goes on). Raises
        what ended the run early, after sending STOPPED. Ctrl-C while waiting stops the
        arm (STOPPED resent until ACKed), then KeyboardInterrupt propagates."""
    def cancel(self) -> None:
        """Sends STOPPED (resent until ACKed; NoReplyError if never) and waits for the
        run to end."""

class Locations(Iterator[Location]):
    def __iter__(self) -> "Locations": ...
    def __next__(self) -> Location: ...

class Arm:
    """A connection to one controller; a context manager that closes it (and stops a
    run or RETURN it started that may be under way when the block ends by an exception:
    STOPPED resent until ACKed, before the exception propagates)."""

    @property
    def address(self) -> str: ...
    def __enter__(self) -> "Arm": ...
    def __exit__(self, exc_type: Any = None, exc_value: Any = None, traceback: Any = None) -> bool: ...
    def close(self) -> None: ...
    def status(self) -> Status: ...
    @overload
    def positions(self) -> npt.NDArray[np.int32]:
        """Joint positions in steps, one per joint in use."""
    @overload
    def positions(
        self, config: Optional[_Path] = None, units: Optional[_Units] = None,
    ) -> Union[npt.NDArray[np.int32], npt.NDArray[np.float64]]:
        """With a joint `config`: in `units` (default the config's `units`), float64, as
        `armctl watch --config` shows them; int32 steps when the units are steps."""
    @overload
    def run(
        self,
        times: npt.ArrayLike,
        positions: npt.ArrayLike,
        config: Optional[_Path] = None,
        wait: Literal[True] = True,
        segment_ms: float = 10.0,
        window: Optional[int] = None,
        units: Optional[_Units] = None,
        speed: Optional[int] = None,
    ) -> RunReport:
        """Runs through waypoints: `times` (N,) seconds, strictly increasing; `positions`
        (N, J) in `units`: default the joint `config` file's `units` when it states them,
        else radians with a config (a JointTrajectory's) and steps without; "deg" and
        "rad" need a config. With a config, joints the arrays leave out hold, and a
        refusal names the joint as the config does and gives positions in `units` too.
        Returns the report (wait) or a RunHandle (wait=False). `speed`: run at this
        percent of the planned speed, 1..200 (OVERRIDE, issue 32; it stays for later runs
        until changed)."""
    @overload
    def run(
        self,
        times: npt.ArrayLike,
        positions: npt.ArrayLike,
        config: Optional[_Path] = None,
        *,
        wait: Literal[False],
        segment_ms: float = 10.0,
        window: Optional[int] = None,
        units: Optional[_Units] = None,
        speed: Optional[int] = None,
    ) -> RunHandle: ...
    @overload
    def run(
        self,
        times: npt.ArrayLike,
        positions: npt.ArrayLike,
        config: Optional[_Path] = None,
        wait: bool = True,
        segment_ms: float = 10.0,
        window: Optional[int] = None,
        units: Optional[_Units] = None,
        speed: Optional[int] = None,
    ) -> Union[RunReport, RunHandle]: ...
    @overload
    def run_file(
        self,
        path: _Path,
        config: Optional[_Path] = None,
        wait: Literal[True] = True,
        segment_ms: float = 10.0,
        window: Optional[int] = None,
        units: Optional[_Units] = None,
        speed: Optional[int] = None,
    ) -> RunReport:
        """Runs a JointTrajectory JSON (radians, with `config`) or CSV file (in `units`,
        default the config's `units`, else steps; joints the CSV leaves out hold). Every
        waypoint ends a segment: none is skipped."""
    @overload
    def run_file(
        self,
        path: _Path,
        config: Optional[_Path] = None,
        *,
        wait: Literal[False],
        segment_ms: float = 10.0,
        window: Optional[int] = None,
        units: Optional[_Units] = None,
        speed: Optional[int] = None,
    ) -> RunHandle: ...
    @overload
    def run_file(
        self,
        path: _Path,
        config: Optional[_Path] = None,
        wait: bool = True,
        segment_ms: float = 10.0,
        window: Optional[int] = None,
        units: Optional[_Units] = None,
        speed: Optional[int] = None,
    ) -> Union[RunReport, RunHandle]: ...
    @overload
    def move_to(
        self,
        targets: Sequence[Optional[float]],
        config: Optional[_Path] = None,
        units: Optional[_Units] = None,
        speed: float = 0.5,
        relative: bool = False,
        segment_ms: float = 10.0,
        wait: Literal[True] = True,
    ) -> Optional[RunReport]:
        """Moves joints to `targets` (joint 0 first, None holds) in `units` (default the
        config's, else steps) on one speed profile within each joint's limits, at `speed`
        (fraction of the step rate). None when already there."""
    @overload
    def move_to(
        self,
        targets: Sequence[Optional[float]],
        config: Optional[_Path] = None,
        units: Optional[_Units] = None,
        speed: float = 0.5,
        relative: bool = False,
        segment_ms: float = 10.0,
        *,
        wait: Literal[False],
    ) -> Optional[RunHandle]: ...
    def jog(
        self,
        joint: Union[int, str],
        by: float,
        config: Optional[_Path] = None,
        units: Optional[_Units] = None,
        speed: float = 0.5,
    ) -> Optional[RunReport]:
        """Moves one joint (index, or name in `config`) by `by` in `units`."""
    @overload
    def home(self, timeout: float = 600.0) -> npt.NDArray[np.int32]:
        """Homes on the switches when the arm has them (HOME, issue 33; raises naming
        the joint if the cycle fails), else RETURN to its end; then the positions (after
        RETURN all 0; raises if a joint ended elsewhere)."""
    @overload
    def home(
        self, timeout: float = 600.0, config: Optional[_Path] = None,
        units: Optional[_Units] = None,
    ) -> Union[npt.NDArray[np.int32], npt.NDArray[np.float64]]:
        """With a joint `config`: positions and the message in `units` (default the
        config's), joints by name, as `armctl home --config`."""
    def set_homing(
        self, joint: int, max_travel_steps: int, towards: Literal["min", "max"] = "min",
        seek_rate_hz: int = 2000, approach_rate_hz: int = 200, backoff_steps: int = 400,
        offset: int = 0, order: int = 0, switch_is_limit: bool = False, enabled: bool = True,
    ) -> None:
        """HOMING_SET (issue 33): the joint homes on its home switch; `home()` runs the
        cycle. Kept across power cycles; only while STOPPED."""
    def switches(self) -> Optional[Dict[str, Any]]:
        """The SWITCHES report (issue 33): `phase` ("never", "homing", "homed",
        "failed"), `joint`, `error`, masks `homed`, `home_active`, `min_active`,
        `max_active`, and `latched` (None or {"joint", "side"}); None from an older
        controller."""
    def stop(self) -> None:
        """STOPPED: every joint stops at once, the trajectory is dropped."""
    def hold(self) -> None:
        """HOLD (issue 32): the run decelerates along its path to a standstill and waits
        (from any host); `resume()` goes on, `stop()` still stops at once."""
    def resume(self) -> None:
        """RESUME (issue 32): after a hold, back to the speed override and on."""
    def override(self, percent: int) -> None:
        """OVERRIDE (issue 32): run at `percent` of the planned speed (1..200), ramped in
        for the run under way and kept for later runs; above 100 % only where every
        joint's rate and acceleration allow (else RefusedError OVERRIDE_REFUSED)."""
    def estop_category(self, category: Optional[int] = None) -> int:
        """The wired e-stop input's stop category (issue 32): with `category` (0 or 1)
        sets it (only while STOPPED; kept in the controller's settings); returns it as the
        controller reports it (0 from a controller older than issue 32). 0: every joint
        stops at once; 1: the run decelerates along its path, then the drivers are
        disabled."""
    def go_home(self, wait: bool = True, timeout: float = 600.0) -> None:
        """RETURN: every joint to zero; with `wait`, until the move ended (at most
        `timeout` s). Ctrl-C or an error while waiting sends STOPPED (resent until ACKed),
        then the exception propagates."""
    def set_location(self, positions: Any) -> None: ...
    def set_joints(self, joints: int) -> None: ...
    def pin(self, pin: int, high: bool) -> None: ...
    def limits(self) -> List[JointLimits]:
        """LIMITS_GET: the limits kept on the controller, one dict per joint 0-7."""
        ...
    def set_limits(
        self,
        joint: int,
        *,
        min: Optional[int] = None,
        max: Optional[int] = None,
        max_rate_hz: Optional[int] = None,
    ) -> None:
        """LIMITS_SET: joint's position range (steps) and step rate (0: the controller's
        own only), kept across power cycles and enforced by the controller on every point,
        RETURN and set_location. Arguments not given keep their value. Only while
        STOPPED."""
        ...
    def joint_description(self, joint: int) -> JointDescription:
        """JOINT_DESC_GET: what the controller keeps of `joint` (issue 31). Any host may
        ask."""
        ...
    def set_joint_description(
        self,
        joint: int,
        *,
        name: Optional[str] = None,
        unit: Optional[str] = None,
        zero_offset: Optional[int] = None,
        scale: Optional[float] = None,
    ) -> None:
        """JOINT_DESC_SET: change what the controller keeps of `joint` (the arguments
        given; the rest as kept): its name (16 bytes at most), unit ('steps', 'deg', 'rad',
        'mm'), zero offset (steps) and scale (steps per radian, per mm or 1; 0 clears the
        description). Every host then names and shows it alike. Only while STOPPED."""
        ...
    def push_config(self, path: _Path) -> List[str]:
        """What `armctl config push PATH` does (the same code): the joint config's (or a
        `config get --json` output's) limits, accelerations and descriptions kept on the
        controller. Returns the lines the CLI prints for them; a controller older than
        issue 31 gives UserWarnings. Only while STOPPED."""
        ...
    def release(self) -> None:
        """RELEASE: give the controller up (only while STOPPED): another host may take it
        at once instead of after 5 s of silence."""
        ...
    def enable(self, joints: Optional[List[int]] = None, *, gripper: Optional[bool] = None) -> None:
        """SET_ENABLE: enable (holding) the drivers of `joints` (0-7), and the gripper's
        with gripper=True; no `joints`: every driver (the gripper too unless
        gripper=False). Only while STOPPED; the other drivers keep their state."""
        ...
    def disable(self, joints: Optional[List[int]] = None, *, gripper: Optional[bool] = None) -> None:
        """SET_ENABLE: disable (limp) the drivers of `joints`, as enable()."""
        ...
    def set_key(self, key_file: Optional[_Path] = None) -> None:
        """SET_KEY: store the key of `key_file` (64 hex digits) in the controller, or
        clear it (None). The first key is set plain; a key set already only by a
        connection made with it."""
        ...
    def pwm_servo(self, duty: float, freq: float = 50.0) -> None: ...
    def pwm_stepper(self, pulses: int, freq: float = 1000.0) -> None: ...
    def pwm_stop(self) -> None: ...
    def serial_open(self, baud: int = 115200) -> None:
        """USART_START at `baud` (8N1); what the port receives is kept for serial_read."""
    def serial_write(self, data: bytes) -> None:
        """USART_SEND: `data` to the serial port, in order."""
    def serial_read(self, timeout: float = 1.0) -> bytes:
        """What the port received: waits up to `timeout` s for the first bytes."""
    def serial_close(self) -> None:
        """USART_STOP."""
    def net_set(self, ip: Optional[str] = None, gateway: Optional[str] = None, dhcp: bool = False) -> None:
        """NET_SET: store 'A.B.C.D/P' (with an optional gateway) or DHCP; used from the
        controller's next reset. Owner only, not while running (RefusedError)."""
    def locations(self, count: Optional[int] = None, timeout: float = 1.0) -> Locations:
        """LOCATION reports as they arrive; ends after `count` or `timeout` s of silence."""

class Found(TypedDict, total=False):
    address: str
    """Where the answer came from: the address in use, 'A.B.C.D:8510'."""
    mac: str
    version: Tuple[int, int, int]
    joints: int
    state: str
    owner: str
    """'free', 'owned' or 'owned by you'."""
    owner_ip: str
    dhcp: bool
    stored_ip: str
    prefix_len: int
    gateway: str
    pending_reset: bool
    """The stored settings take effect at the next reset."""

def discover(
    to: str = "255.255.255.255:8510",
    *,
    wait: float = 0.3,
    rounds: int = 2,
    bind: Optional[str] = None,
) -> List[Found]:
    """DISCOVER to a broadcast address or one controller; one dict per controller that
    answered (a controller without DISCOVER gives only 'address'). Changes nothing."""

def connect(
    address: str = "127.0.0.1:8510",
    *,
    ack_timeout: float = 0.1,
    attempts: int = 10,
    bind: Optional[str] = None,
    pcap: Optional[_Path] = None,
    key_file: Optional[_Path] = None,
) -> Arm:
    """Connects and checks the controller answers STATUS (NoReplyError otherwise).
    `pcap`: write every datagram to this capture file (for Wireshark). From the main
    thread, installs armctl's SIGTERM/SIGHUP handler where none is set (see the module's
    doc)."""
