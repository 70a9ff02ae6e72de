//! The wire's code tables (tags, states, status codes): each declared once by
//! [`wire_code!`], which makes the enum and its conversions from the one list.

/// Declares a `#[repr(u8)]` wire code: each variant with its doc comment, its byte and its
/// upper-case name as docs/PROTOCOL.md spells it (`Variant = 0x00 => "NAME",`). Generates
/// `ALL`, `from_u8`, `TryFrom<u8>`, `From<_> for u8`, `name`, `name_of`, `from_name` and
/// `Display` (the name), so that no other crate keeps a table of its own.
macro_rules! wire_code {
    (
        $(#[$meta:meta])*
        pub enum $code:ident {
            $(
                $(#[$variant_meta:meta])*
                $variant:ident = $byte:literal => $name:literal,
            )+
        }
    ) => {
        $(#[$meta])*
        #[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
        #[cfg_attr(feature = "defmt", derive(defmt::Format))]
        #[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
        #[repr(u8)]
        pub enum $code {
            $(
                $(#[$variant_meta])*
                $variant = $byte,
            )+
        }

        impl $code {
            /// Every value, in the order of their bytes.
            pub const ALL: &'static [$code] = &[$($code::$variant),+];

            /// The value for a byte, if there is one.
            pub const fn from_u8(b: u8) -> Option<$code> {
                match b {
                    $($byte => Some($code::$variant),)+
                    _ => None,
                }
            }

            /// The upper-case name, as docs/PROTOCOL.md spells it.
            pub const fn name(self) -> &'static str {
                match self {
                    $($code::$variant => $name,)+
                }
            }

            /// The name of the value of byte `b`, or "?" if no value has it (for logs and
            /// displays of bytes as received).
            pub const fn name_of(b: u8) -> &'static str {
                match $code::from_u8(b) {
                    Some(code) => code.name(),
                    None => "?",
                }
            }

            /// The value [`name`](Self::name) gives `name` for, if there is one.
            pub fn from_name(name: &str) -> Option<$code> {
                Self::ALL.iter().copied().find(|c| c.name() == name)
            }
        }

        impl TryFrom<u8> for $code {
            /// The byte that names no value.
            type Error = u8;
            fn try_from(b: u8) -> Result<$code, u8> {
                $code::from_u8(b).ok_or(b)
            }
        }

        impl From<$code> for u8 {
            fn from(code: $code) -> u8 {
                code as u8
            }
        }

        impl core::fmt::Display for $code {
            fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
                f.write_str(self.name())
            }
        }
    };
}
pub(crate) use wire_code;

wire_code! {
    /// A frame's tag byte: the command or report it carries. Its name is the command's
    /// (host direction): 0x13 is "LOCATION_SETTING" (the report is LOCATION).
    pub enum Tag {
        /// Start an upload of `count` points.
        New = 0x00 => "NEW",
        /// 1..12 trajectory points.
        Pending = 0x01 => "PENDING",
        /// Start executing (the manual's spelling).
        Runing = 0x02 => "RUNING",
        /// Stop at once, drop the buffer.
        Stopped = 0x03 => "STOPPED",
        /// Location reports on.
        UploadStart = 0x04 => "UPLOAD_START",
        /// Location reports off.
        UploadStop = 0x05 => "UPLOAD_STOP",
        /// Gripper PWM on.
        PwmStart = 0x06 => "PWM_START",
        /// Gripper PWM off.
        PwmStop = 0x07 => "PWM_STOP",
        /// Open the pass-through serial port.
        UsartStart = 0x08 => "USART_START",
        /// Close it.
        UsartStop = 0x09 => "USART_STOP",
        /// Bytes to write to the serial port.
        UsartSend = 0x0a => "USART_SEND",
        /// Bytes read from the serial port (controller to host).
        UsartRecv = 0x0b => "USART_RECV",
        /// GPIO_0 high.
        Pin0On = 0x0c => "PIN0_ON",
        /// GPIO_0 low.
        Pin0Off = 0x0d => "PIN0_OFF",
        /// GPIO_1 high.
        Pin1On = 0x0e => "PIN1_ON",
        /// GPIO_1 low.
        Pin1Off = 0x0f => "PIN1_OFF",
        /// Toggle driver ENABLE lines.
        ToggleEnablePins = 0x10 => "TOGGLE_ENABLE_PINS",
        /// Move every joint to zero.
        Return = 0x11 => "RETURN",
        /// Set the number of joints.
        JointsCount = 0x12 => "JOINTS_COUNT",
        /// LOCATION_SETTING (host to controller) or LOCATION (controller to host).
        Location = 0x13 => "LOCATION_SETTING",
        /// ACK (controller to host).
        Ack = 0x14 => "ACK",
        /// STATUS request or report.
        Status = 0x15 => "STATUS",
        /// Location report period.
        UploadPeriod = 0x16 => "UPLOAD_PERIOD",
        /// Clear the wired e-stop input's latch (refused while the input is open).
        EstopReset = 0x17 => "ESTOP_RESET",
        /// Enable or disable the masked drivers explicitly (issue 23; TOGGLE_ENABLE_PINS
        /// stays for old hosts).
        SetEnable = 0x18 => "SET_ENABLE",
        /// The owner gives the controller up: any host may take it at once (issue 23).
        Release = 0x19 => "RELEASE",
        /// Set one joint's position range and step rate, kept across power cycles
        /// (issue 23).
        LimitsSet = 0x1a => "LIMITS_SET",
        /// Ask for the LIMITS report.
        LimitsGet = 0x1b => "LIMITS_GET",
        /// Every joint's limits and the last refusal (controller to host).
        Limits = 0x1c => "LIMITS",
        /// What ended the last run and who sent the STOPPED (controller to host; asked
        /// for with STATUS's request byte, bit 2; issue 31).
        StopCause = 0x1d => "STOP_CAUSE",
        /// Set one joint's most acceleration, steps/s², kept with its limits (issue 31).
        AccelSet = 0x1e => "ACCEL_SET",
        /// Set one joint's description: name, units, scale (issue 31), kept with its
        /// limits.
        JointDescSet = 0x1f => "JOINT_DESC_SET",
        /// Who is there? Answered by every controller, from any host (PROTOCOL.md,
        /// "Finding controllers and setting their address").
        Discover = 0x20 => "DISCOVER",
        /// Store the controller's network settings (applied after a reset).
        NetSet = 0x21 => "NET_SET",
        /// The answer to DISCOVER (controller to host).
        DiscoverReply = 0x22 => "DISCOVER_REPLY",
        /// Ask for one joint's JOINT_DESC report (issue 31; any host, read-only).
        JointDescGet = 0x23 => "JOINT_DESC_GET",
        /// The receive path's counters, asked for by STATUS's request byte bit 3
        /// (controller to host; issue 30).
        RxCounters = 0x24 => "RX_COUNTERS",
        /// Clear the hard-limit latch after a limit switch tripped (issue 33); then only
        /// motion away from a switch still active is accepted.
        Unlock = 0x25 => "UNLOCK",
        /// One joint's description (controller to host; issue 31).
        JointDesc = 0x26 => "JOINT_DESC",
        /// The board's own timing counters, asked for by STATUS's request byte bit 6
        /// (controller to host; issue 34).
        Diag = 0x32 => "DIAG",
        /// Decelerate the run along its path to a standstill and wait (issue 32; any
        /// host, as STOPPED).
        Hold = 0x27 => "HOLD",
        /// Go on after a HOLD: accelerate back to the override (issue 32; the owner).
        Resume = 0x28 => "RESUME",
        /// Set the speed override, percent 1..200 (issue 32; the owner).
        Override = 0x29 => "OVERRIDE",
        /// The override, hold and ramp state (controller to host; asked for with
        /// STATUS's request byte bit 4; issue 32).
        Motion = 0x2a => "MOTION",
        /// Set the wired e-stop input's stop category, 0 or 1 (issue 32), kept in the
        /// settings; read back in MOTION's byte 7.
        EstopCategory = 0x2b => "ESTOP_CATEGORY",
        /// Run the homing cycle on the home switches (issue 33; no data; RETURN is
        /// unchanged).
        Home = 0x2c => "HOME",
        /// Set one joint's homing settings, kept with its limits (issue 33).
        HomingSet = 0x2d => "HOMING_SET",
        /// Ask for one joint's HOMING report (issue 33; the owner, as LIMITS_GET).
        HomingGet = 0x2e => "HOMING_GET",
        /// One joint's homing settings (controller to host; issue 33).
        Homing = 0x2f => "HOMING",
        /// The homing cycle's progress and the switch inputs (controller to host; asked
        /// for with STATUS's request byte, bit 5; issue 33).
        Switches = 0x30 => "SWITCHES",
        /// An authenticated envelope around a whole frame, both directions
        /// (docs/PROTOCOL.md section 13, [`crate::auth`]).
        Auth = 0x50 => "AUTH",
        /// Open an authenticated session: a host nonce (answered with HELLO_REPLY).
        Hello = 0x51 => "HELLO",
        /// Set (32 bytes) or clear (no data) the controller's key.
        SetKey = 0x52 => "SET_KEY",
        /// The answer to HELLO: nonce, epoch, session (controller to host, in an envelope).
        HelloReply = 0x53 => "HELLO_REPLY",
    }
}

wire_code! {
    /// The trajectory state machine's state, as LOCATION, ACK and STATUS carry it.
    #[derive(Default)]
    pub enum State {
        /// NEW arrived; waiting for the first points.
        New = 0 => "NEW",
        /// Points arriving; not moving.
        Pending = 1 => "PENDING",
        /// Executing the buffered points.
        Running = 2 => "RUNNING",
        /// Idle: boot, after a run, after STOPPED.
        #[default]
        Stopped = 3 => "STOPPED",
    }
}

wire_code! {
    /// An ACK's status: 0 = done, anything else = the command did nothing. Names as in
    /// docs/PROTOCOL.md, "Status codes (the ACK's `status`)".
    pub enum StatusCode {
        /// Done.
        Ok = 0 => "OK",
        /// CRC mismatch; nothing done.
        BadCrc = 1 => "BAD_CRC",
        /// No such command.
        UnknownTag = 2 => "UNKNOWN_TAG",
        /// Data length wrong for the tag.
        BadLength = 3 => "BAD_LENGTH",
        /// Not allowed in the current state.
        BadState = 4 => "BAD_STATE",
        /// PENDING seq is not `next_seq`.
        OutOfOrder = 5 => "OUT_OF_ORDER",
        /// More points than NEW announced.
        TooManyPoints = 6 => "TOO_MANY_POINTS",
        /// A point breaks the trajectory rules (step rate, duration).
        InvalidPoint = 7 => "INVALID_POINT",
        /// Not enough free buffer slots.
        BufferFull = 8 => "BUFFER_FULL",
        /// Another host owns the controller.
        NotOwner = 9 => "NOT_OWNER",
        /// Not a command a host may send.
        Unsupported = 10 => "UNSUPPORTED",
        /// A configuration value out of range.
        InvalidConfig = 11 => "INVALID_CONFIG",
        /// RUNING or RETURN while the wired e-stop input is open or its latch is not yet
        /// cleared (ESTOP_RESET); also ESTOP_RESET while the input is still open.
        EstopLatched = 12 => "ESTOP_LATCHED",
        /// The controller has a key and the frame was not in an envelope (only STOPPED,
        /// DISCOVER and HELLO pass without one).
        AuthRequired = 13 => "AUTH_REQUIRED",
        /// An envelope that did not verify: wrong MAC (another key, or a controller reset
        /// since HELLO), an unknown session, or a counter already used (a replay).
        AuthFailed = 14 => "AUTH_FAILED",
        /// A command that writes the settings to flash (JOINTS_COUNT, LIMITS_SET, SET_KEY,
        /// NET_SET) whose save failed: nothing changed (issue 30).
        SaveFailed = 15 => "SAVE_FAILED",
        /// A limit switch tripped (issue 33): RUNING and RETURN are refused until a host
        /// sends UNLOCK; after it, points moving a joint further into a limit switch still
        /// active are refused with this code too.
        LimitLatched = 16 => "LIMIT_LATCHED",
        /// OVERRIDE above 100 % where a joint's step rate or acceleration does not allow
        /// it (the MOTION report names the joint and the limit; issue 32).
        OverrideRefused = 17 => "OVERRIDE_REFUSED",
        /// The safety door is open (issue 32): RUNING and RESUME are refused until it is
        /// closed (an open door holds a run; closing it and a RESUME go on).
        DoorOpen = 18 => "DOOR_OPEN",
        /// HOME refused: no joint in use is set to home on a switch (HOMING_SET), or the
        /// controller has no switch inputs (issue 33). How a cycle ended is in the
        /// SWITCHES report.
        HomingFailed = 20 => "HOMING_FAILED",
    }
}

impl StatusCode {
    /// A refusal these bytes can never turn into an acceptance, whatever the controller's
    /// state (malformed, or a setting the board cannot make). Such a command other than
    /// PENDING fills its seq in an upload's order (docs/PROTOCOL.md section 7, issue 21
    /// F12); a refusal a resend can change (`BAD_STATE`, `ESTOP_LATCHED`, `BUFFER_FULL`)
    /// does not.
    pub const fn refuses_for_good(self) -> bool {
        matches!(
            self,
            StatusCode::UnknownTag
                | StatusCode::BadLength
                | StatusCode::InvalidConfig
                | StatusCode::Unsupported
                | StatusCode::InvalidPoint
                | StatusCode::TooManyPoints
        )
    }

    /// What a host should do about it.
    pub const fn advice(self) -> &'static str {
        use StatusCode::*;
        match self {
            Ok => "nothing",
            BadCrc => "the frame was damaged on the way: resend it",
            UnknownTag => "the controller has no such command: check the tag",
            BadLength => "the data length is wrong for this command: check the encoder",
            BadState => {
                "not allowed in the controller's current state: STOP it or wait for the run to end"
            }
            OutOfOrder => "a PENDING frame was lost: resend from the ACK's next_seq",
            TooManyPoints => "more points than NEW announced: send NEW with the right count",
            InvalidPoint => {
                "a point asks for more than the controller's max step rate or a joint's limits, has a duration under 1 us, or moves a joint whose driver is disabled (LIMITS_GET says which)"
            }
            BufferFull => "the trajectory buffer is full: resend when the ACK's `free` allows",
            NotOwner => {
                "another host owns the controller: wait 5 s after it goes quiet, or have it release the arm (RELEASE, `armctl release`)"
            }
            Unsupported => "this frame only goes from controller to host",
            InvalidConfig => {
                "a value is out of its range (PWM, serial, joint count, point count, upload period)"
            }
            EstopLatched => {
                "the wired e-stop input was opened: close it, then clear the latch with ESTOP_RESET"
            }
            AuthRequired => {
                "the controller has a key: give the key (armctl --key-file) to send authenticated frames"
            }
            AuthFailed => {
                "authentication failed: wrong key, or the controller was reset (open a new session with HELLO)"
            }
            LimitLatched => {
                "a limit switch tripped: `armctl unlock`, then move that joint away from the switch (motion further in is refused while it is active)"
            }
            OverrideRefused => {
                "the run is too fast for that override: a joint's step rate or acceleration would go over its limit (STATUS's MOTION report names the joint); ask 100 % or less"
            }
            DoorOpen => "the safety door is open: close it, then RUNING (or RESUME a held run)",
            HomingFailed => {
                "no joint is set to home on a switch, or the controller has no switch inputs: HOMING_SET each joint (armctl homing set), or home by RETURN"
            }
            SaveFailed => {
                "the controller could not save its settings to flash: nothing changed; retry, and if it keeps failing the flash needs looking at (see the board's log)"
            }
        }
    }
}
