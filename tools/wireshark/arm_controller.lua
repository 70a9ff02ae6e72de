-- Wireshark dissector for the arm controller's UDP protocol (docs/PROTOCOL.md).
--
-- Install: copy this file into Wireshark's personal Lua plugins folder (Help > About >
-- Folders > "Personal Lua Plugins", e.g. ~/.local/lib/wireshark/plugins/), or run
-- `tshark -X lua_script:tools/wireshark/arm_controller.lua -r capture.pcap`.
-- docs/WIRESHARK.md has the details.
--
-- A frame is | seq u8 | tag u8 | data | crc u8 | (CRC-8/SMBUS over seq, tag and data).
-- Tags 0x13 and 0x15 travel both ways with different contents (LOCATION_SETTING from a
-- host / LOCATION from the controller; a STATUS request / the STATUS report): the
-- direction is decided by the port, 8510 being the controller's (Edit > Preferences >
-- Protocols > ARMCTL to change it, or Decode As for a simulator on another port).
--
-- Analysis (done on the first pass over a capture): each command is paired with its ACK
-- (armctl.response_in / armctl.response_to, round trip armctl.time; copies of a resent
-- command are paired with the ACKs in the order they came), and a command sent
-- again with the same bytes by the same host port is marked as a retransmission of the
-- first copy (armctl.retransmission, with an expert note).

local armctl = Proto("armctl", "Arm controller protocol")

local DEFAULT_PORT = 8510
armctl.prefs.port = Pref.uint("Controller UDP port", DEFAULT_PORT,
    "UDP port the controller listens on: datagrams to it are commands, from it reports")
armctl.prefs.key = Pref.string("Authentication key", "",
    "The controllers' key, 64 hex digits (docs/PROTOCOL.md section 13): AUTH envelopes' " ..
    "MACs are checked with it (the boot epoch is taken from the HELLO_REPLY seen before)")

----------------------------------------------------------------------------------------
-- Value names

local tag_names = {
    [0x00] = "NEW", [0x01] = "PENDING", [0x02] = "RUNING", [0x03] = "STOPPED",
    [0x04] = "UPLOAD_START", [0x05] = "UPLOAD_STOP", [0x06] = "PWM_START",
    [0x07] = "PWM_STOP", [0x08] = "USART_START", [0x09] = "USART_STOP",
    [0x0a] = "USART_SEND", [0x0b] = "USART_RECV", [0x0c] = "PIN0_ON", [0x0d] = "PIN0_OFF",
    [0x0e] = "PIN1_ON", [0x0f] = "PIN1_OFF", [0x10] = "TOGGLE_ENABLE_PINS",
    [0x11] = "RETURN", [0x12] = "JOINTS_COUNT", [0x13] = "LOCATION_SETTING/LOCATION",
    [0x14] = "ACK", [0x15] = "STATUS", [0x16] = "UPLOAD_PERIOD", [0x17] = "ESTOP_RESET",
    [0x18] = "SET_ENABLE", [0x19] = "RELEASE", [0x1a] = "LIMITS_SET", [0x1b] = "LIMITS_GET",
    [0x1c] = "LIMITS", [0x1d] = "STOP_CAUSE", [0x1e] = "ACCEL_SET", [0x1f] = "JOINT_DESC_SET",
    [0x20] = "DISCOVER", [0x21] = "NET_SET", [0x22] = "DISCOVER_REPLY",
    [0x23] = "JOINT_DESC_GET", [0x24] = "RX_COUNTERS", [0x25] = "UNLOCK", [0x26] = "JOINT_DESC",
    [0x27] = "HOLD", [0x28] = "RESUME", [0x29] = "OVERRIDE", [0x2a] = "MOTION", [0x32] = "DIAG",
    [0x2b] = "ESTOP_CATEGORY", [0x2c] = "HOME", [0x2d] = "HOMING_SET", [0x2e] = "HOMING_GET", [0x2f] = "HOMING",
    [0x30] = "SWITCHES",
    [0x50] = "AUTH", [0x51] = "HELLO", [0x52] = "SET_KEY", [0x53] = "HELLO_REPLY",
}
-- Names that depend on the direction.
local host_names = { [0x13] = "LOCATION_SETTING", [0x15] = "STATUS request" }
local controller_names = { [0x13] = "LOCATION", [0x15] = "STATUS report" }

-- JOINT_DESC's unit byte (issue 31).
local desc_unit_names = { [0] = "steps", [1] = "deg", [2] = "rad", [3] = "mm" }

local state_names = { [0] = "NEW", [1] = "PENDING", [2] = "RUNNING", [3] = "STOPPED" }

local status_names = {
    [0] = "OK", [1] = "BAD_CRC", [2] = "UNKNOWN_TAG", [3] = "BAD_LENGTH", [4] = "BAD_STATE",
    [5] = "OUT_OF_ORDER", [6] = "TOO_MANY_POINTS", [7] = "INVALID_POINT", [8] = "BUFFER_FULL",
    [9] = "NOT_OWNER", [10] = "UNSUPPORTED", [11] = "INVALID_CONFIG", [12] = "ESTOP_LATCHED",
    [13] = "AUTH_REQUIRED", [14] = "AUTH_FAILED", [15] = "SAVE_FAILED",
    [16] = "LIMIT_LATCHED", [17] = "OVERRIDE_REFUSED", [18] = "DOOR_OPEN", [20] = "HOMING_FAILED",
}

-- The SWITCHES report's phase and error bytes (issue 33).
local homing_phase_names = { [0] = "never homed", [1] = "homing", [2] = "homed", [3] = "failed" }
local homing_error_names = {
    [0] = "none", [1] = "seek travelled its maximum", [2] = "switch still pressed after back-off",
    [3] = "approach missed the switch", [4] = "aborted", [5] = "bad settings",
}
-- MOTION's last controlled stop and refused limit (issue 32).
local controlled_stop_names = {
    [0] = "NONE", [1] = "HOLD", [2] = "UNDERRUN", [3] = "DOOR", [4] = "ESTOP",
}
-- The wired e-stop input's stop category (ESTOP_CATEGORY, MOTION byte 7; issue 32).
local estop_category_names = { [0] = "CATEGORY_0", [1] = "CATEGORY_1" }
local override_limit_names = { [0] = "none", [1] = "RATE", [2] = "ACCEL", [3] = "STEP_BUDGET" }

local crc_status_names = { [0] = "Bad", [1] = "Good", [2] = "Unverified" }
local direction_names = { [0] = "host to controller", [1] = "controller to host" }
local uart_mode_names = { [0] = "both directions", [1] = "receive only", [2] = "transmit only" }
local owner_names = { [0] = "no owner", [1] = "owned", [2] = "owned by the asking host" }
local addr_mode_names = { [0] = "static", [1] = "DHCP" }
local refusal_names = {
    [0] = "nothing refused", [1] = "below min", [2] = "above max", [3] = "over the joint's max rate",
    [4] = "over max_step_rate_hz", [5] = "over step_budget_hz", [6] = "duration or step count",
    [7] = "the joint's driver is disabled", [8] = "over the joint's max acceleration",
}
-- What ended the last run (STATUS more_flags bits 5-7, the STOP_CAUSE report; issue 31).
local stop_cause_names = {
    [0] = "not reported (older controller)", [1] = "COMPLETE", [2] = "STOPPED",
    [3] = "ESTOP_INPUT", [4] = "UNDERRUN", [5] = "FAULT", [6] = "LIMIT_SWITCH", [7] = "HOLD",
}
local enable_action_names = { [0] = "disable (limp)", [1] = "enable (holding)" }

----------------------------------------------------------------------------------------
-- Fields

-- A field "armctl.<name>" of Wireshark type `kind`; the rest as ProtoField.<kind> takes it.
local function field(kind, name, label, ...)
    return ProtoField[kind]("armctl." .. name, label, ...)
end

-- A number field shown in decimal, with value names if `names` is given.
local function dec(kind, name, label, names)
    if names then return field(kind, name, label, base.DEC, names) end
    return field(kind, name, label, base.DEC)
end

-- A number field shown in hex, with value names if `names` is given.
local function hex(kind, name, label, names)
    if names then return field(kind, name, label, base.HEX, names) end
    return field(kind, name, label, base.HEX)
end

-- One bit of STATUS `flags`.
local function status_flag(name, label, mask)
    return field("bool", "status.flags." .. name, label, 8, nil, mask)
end

local f = {
    -- authentication (PROTOCOL.md section 13)
    auth_session = dec("uint32", "auth.session", "Session"),
    auth_counter = dec("uint64", "auth.counter", "Counter"),
    auth_inner = field("none", "auth.inner", "Inner frame"),
    auth_mac = field("bytes", "auth.mac", "MAC (keyed BLAKE2s-128)"),
    auth_mac_status = dec("uint8", "auth.mac.status", "MAC status",
        { [0] = "Bad", [1] = "Good", [2] = "Unverified (no key in the preferences, or no HELLO_REPLY seen)" }),
    hello_nonce = field("bytes", "hello.nonce", "Nonce"),
    hello_epoch = dec("uint64", "hello.epoch", "Boot epoch"),
    set_key = field("bytes", "set_key.key", "Key"),
    seq = dec("uint8", "seq", "Sequence number"),
    tag = hex("uint8", "tag", "Tag", tag_names),
    direction = dec("uint8", "direction", "Direction", direction_names),
    data = field("bytes", "data", "Data"),
    crc = hex("uint8", "crc", "CRC-8/SMBUS"),
    crc_status = dec("uint8", "crc.status", "CRC status", crc_status_names),
    crc_computed = hex("uint8", "crc.computed", "Computed CRC"),

    -- commands
    new_count = dec("uint16", "new.count", "Point count"),
    points = dec("uint8", "points", "Points in frame"),
    point = field("none", "point", "Point"),
    point_duration = dec("int32", "point.duration", "Duration (us)"),
    point_position = dec("int32", "point.position", "Position (steps)"),
    point_full = dec("int16", "point.number_of_full_period", "numberOfFullPeriod"),
    point_rest = dec("int16", "point.rest_period", "restPeriod"),
    point_nperiod = dec("int16", "point.number_of_period", "numberOfPeriod"),
    point_period = dec("int32", "point.period", "period"),
    pwm_psc = dec("uint32", "pwm.psc", "PSC"),
    pwm_arr = dec("uint32", "pwm.arr", "ARR"),
    pwm_ccr1 = dec("uint32", "pwm.ccr1", "CCR1"),
    pwm_pulse_count = dec("int32", "pwm.pulse_count", "PluseCount"),
    uart_baud = dec("uint32", "uart.baud_rate", "BaudRate"),
    uart_word = hex("uint32", "uart.word_length", "WordLength"),
    uart_stop = hex("uint32", "uart.stop_bits", "StopBits"),
    uart_parity = hex("uint32", "uart.parity", "Parity"),
    uart_parity2 = hex("uint32", "uart.parity_repeated", "Parity (repeated, ignored)"),
    uart_mode = dec("uint32", "uart.mode", "Mode", uart_mode_names),
    uart_flow = hex("uint32", "uart.hw_flow_ctl", "HwFlowCtl"),
    uart_over = hex("uint32", "uart.over_sampling", "OverSampling"),
    usart_len = dec("uint8", "usart.len", "Length"),
    usart_data = field("bytes", "usart.data", "Serial bytes"),
    enable_mask = hex("uint16", "enable.mask", "Enable mask"),
    enable_action = dec("uint8", "enable.action", "Action", enable_action_names),
    status_ask = hex("uint8", "status.ask", "Request byte"),
    limits_joint = dec("uint8", "limits.joint", "Joint"),
    limits_min = dec("int32", "limits.min", "Min (steps)"),
    limits_max = dec("int32", "limits.max", "Max (steps)"),
    limits_rate = dec("uint32", "limits.max_rate_hz", "Max rate (steps/s, 0 = the controller's)"),
    limits_accel = dec("uint32", "limits.max_accel_steps_s2", "Max acceleration (steps/s², 0 = none)"),
    desc_name = field("stringz", "desc.name", "Joint name"),
    desc_unit = dec("uint8", "desc.unit", "Units", desc_unit_names),
    desc_zero = dec("int32", "desc.zero_offset_steps", "Zero offset (steps)"),
    desc_scale = field("double", "desc.scale", "Scale (steps per radian, per mm or per step; 0 = none)"),
    limits_ask = hex("uint8", "limits.ask", "LIMITS_GET request byte (0x01: with the accelerations)"),
    refusal_seq = dec("uint8", "limits.refusal.seq", "Last refused frame's seq"),
    refusal_tag = hex("uint8", "limits.refusal.tag", "Last refused frame's tag", tag_names),
    refusal_point = dec("uint8", "limits.refusal.point", "Point in the frame"),
    refusal_joint = dec("uint8", "limits.refusal.joint", "Joint (255 = all)"),
    refusal_reason = dec("uint8", "limits.refusal.reason", "Reason", refusal_names),
    refusal_value = dec("int32", "limits.refusal.value", "Value asked"),
    refusal_limit = dec("int32", "limits.refusal.limit", "Limit broken"),
    status_ask_location = field("bool", "status.ask.location", "Also a LOCATION report", 8, nil, 0x01),
    status_ask_look = field("bool", "status.ask.look_only", "Look only (never takes the controller)", 8, nil, 0x02),
    status_ask_stop = field("bool", "status.ask.stop_cause", "Also a STOP_CAUSE report", 8, nil, 0x04),
    status_ask_counters = field("bool", "status.ask.counters", "Also an RX_COUNTERS report", 8, nil, 0x08),
    status_ask_diag = field("bool", "status.ask.diag", "Also a DIAG report", 8, nil, 0x40),
    status_ask_motion = field("bool", "status.ask.motion", "Also a MOTION report", 8, nil, 0x10),
    override_percent = dec("uint8", "override.percent", "Override, percent"),
    motion_factor = dec("uint8", "motion.factor", "Override asked, percent"),
    motion_flags = hex("uint8", "motion.flags", "Flags"),
    motion_held = field("bool", "motion.held", "Held (HOLD in force)", 8, nil, 0x01),
    motion_at_rest = field("bool", "motion.at_rest", "At rest", 8, nil, 0x02),
    motion_ramping = field("bool", "motion.ramping", "Ramping", 8, nil, 0x04),
    motion_underrun = field("bool", "motion.underrun", "Underrun ramp (the host is late)", 8, nil, 0x08),
    motion_door_open = field("bool", "motion.door_open", "Safety door open", 8, nil, 0x10),
    motion_estop_ramp = field("bool", "motion.estop_ramp", "Category 1 e-stop ramp", 8, nil, 0x20),
    estop_category = dec("uint8", "estop_category", "E-stop stop category", estop_category_names),
    motion_rate = dec("uint16", "motion.rate", "Rate now, tenths of a percent"),
    motion_last_stop = dec("uint8", "motion.last_stop", "Last controlled stop", controlled_stop_names),
    motion_refused_joint = dec("uint8", "motion.refused_joint", "Last OVERRIDE refused: joint (255 none)"),
    motion_refused_limit = dec("uint8", "motion.refused_limit", "... the limit", override_limit_names),
    status_ask_switches = field("bool", "status.ask.switches", "Also a SWITCHES report", 8, nil, 0x20),
    -- HOMING_SET / HOMING (issue 33)
    homing_joint = dec("uint8", "homing.joint", "Joint"),
    homing_flags = hex("uint8", "homing.flags", "Flags (bit 0 enabled, 1 towards max, 2 switch is the limit)"),
    homing_order = dec("uint8", "homing.order", "Order"),
    homing_seek = dec("uint32", "homing.seek_rate_hz", "Seek rate (steps/s)"),
    homing_approach = dec("uint32", "homing.approach_rate_hz", "Back-off and approach rate (steps/s)"),
    homing_backoff = dec("uint32", "homing.backoff_steps", "Back-off (steps)"),
    homing_travel = dec("uint32", "homing.max_travel_steps", "Max seek travel (steps)"),
    homing_offset = dec("int32", "homing.offset", "Count at the switch (steps)"),
    -- SWITCHES (issue 33)
    sw_phase = dec("uint8", "switches.phase", "Homing", homing_phase_names),
    sw_joint = dec("uint8", "switches.joint", "Joint homing or failed"),
    sw_error = dec("uint8", "switches.error", "Failure", homing_error_names),
    sw_homed = hex("uint8", "switches.homed", "Joints homed"),
    sw_home = hex("uint8", "switches.home_active", "Home switches pressed"),
    sw_min = hex("uint8", "switches.min_active", "Min limits pressed"),
    sw_max = hex("uint8", "switches.max_active", "Max limits pressed"),
    sw_latched = hex("uint8", "switches.latched", "Latched limit (joint | 0x80 max; 0xff none)"),
    stop_cause = dec("uint8", "stop.cause", "What ended the last run", stop_cause_names),
    stop_detail = dec("uint8", "stop.detail", "Detail (FAULT: the joint; UNDERRUN: 1 controlled)"),
    stop_ip = field("ipv4", "stop.from_ip", "STOPPED's sender"),
    stop_port = dec("uint16", "stop.from_port", "STOPPED's sender port"),
    rx_ring_dropped = dec("uint32", "rx.ring_dropped", "Frames the MAC dropped (ring full)"),
    rx_ring_full = dec("uint32", "rx.ring_full", "Times the ring was full"),
    rx_interrupt_stops = dec("uint32", "rx.interrupt_stops", "STOPPEDs halted in the receive interrupt"),
    rx_shed = dec("uint32", "rx.shed", "Datagrams over their sender's share"),
    rx_inbox_dropped = dec("uint32", "rx.inbox_dropped", "Datagrams dropped by a full inbox"),
    rx_group_ignored = dec("uint32", "rx.group_ignored", "Datagrams to a broadcast address ignored"),
    diag_cpu_hz = dec("uint32", "diag.cpu_hz", "Cycle counter clock (Hz, 0 = not measured)"),
    diag_masked_max = dec("uint32", "diag.masked_max_cycles", "Longest masked span (CPU cycles)"),
    diag_masked_opener = hex("uint32", "diag.masked_opener", "Code address that opened it"),
    diag_masked_spans = dec("uint32", "diag.masked_spans", "Masked spans measured"),
    diag_step_hz = dec("uint32", "diag.step_hz", "Step clock (Hz, 0 = not measured)"),
    diag_dir_late = dec("int32", "diag.dir_late_max_ticks", "Latest DIR change after its compare (step ticks)"),
    diag_dir_writes = dec("uint32", "diag.dir_writes", "DIR changes written"),
    diag_dma_slack = dec("uint32", "diag.dma_slack_min_ticks", "Least DMA slack before an update event (step ticks)"),
    diag_dma_refills = dec("uint32", "diag.dma_refills", "Refills measured"),
    joints = dec("uint8", "joints", "Joints"),
    upload_period = dec("uint32", "upload_period_us", "Upload period (us)"),

    -- LOCATION / LOCATION_SETTING
    location_position = dec("int32", "location.position", "Position (steps)"),
    location_state = dec("uint8", "location.state", "State", state_names),

    -- ACK
    ack_acked_tag = hex("uint8", "ack.acked_tag", "Acknowledged tag", tag_names),
    ack_status = dec("uint8", "ack.status", "Status", status_names),
    ack_state = dec("uint8", "ack.state", "State", state_names),
    ack_next_seq = dec("uint8", "ack.next_seq", "Next seq"),
    ack_buffered = dec("uint16", "ack.buffered", "Buffered points"),
    ack_free = dec("uint16", "ack.free", "Free slots"),

    -- STATUS report
    st_version = field("string", "status.version", "Protocol version"),
    st_joints = dec("uint8", "status.joints", "Joints"),
    st_state = dec("uint8", "status.state", "State", state_names),
    st_flags = hex("uint8", "status.flags", "Flags"),
    st_flag_reports = status_flag("reports_on", "Location reports on", 0x01),
    st_flag_drivers = status_flag("drivers_enabled", "Drivers enabled", 0x02),
    st_flag_serial = status_flag("serial_open", "Serial open", 0x04),
    st_flag_pin0 = status_flag("pin0_high", "PIN0 high", 0x08),
    st_flag_pin1 = status_flag("pin1_high", "PIN1 high", 0x10),
    st_flag_underrun = status_flag("underrun", "Last run ended by underrun", 0x20),
    st_flag_pwm = status_flag("pwm_active", "Gripper PWM active", 0x40),
    st_flag_stopped = status_flag("stopped_by_host", "Last run ended by STOPPED", 0x80),
    st_window = dec("uint16", "status.window", "Window (offset 6; 0 = old controller)"),
    st_buffered = dec("uint16", "status.buffered", "Buffered points"),
    st_expected = dec("uint16", "status.expected", "Points announced"),
    st_received = dec("uint16", "status.received", "Points received"),
    st_executed = dec("uint16", "status.executed", "Points executed"),
    st_capacity = dec("uint16", "status.capacity", "Buffer capacity"),
    st_more_flags = hex("uint16", "status.more_flags", "More flags (offset 18)"),
    st_more_dropped = field("bool", "status.more_flags.upload_dropped", "Unstarted upload dropped at a hand-over", 16, nil, 0x0001),
    st_more_estop_open = field("bool", "status.more_flags.estop_open", "Wired e-stop input open", 16, nil, 0x0002),
    st_more_estop_latched = field("bool", "status.more_flags.estop_latched", "E-stop latch set", 16, nil, 0x0004),
    st_more_enables = field("bool", "status.more_flags.enables_reported", "Per-driver enables reported (issue 23)", 16, nil, 0x0008),
    st_more_gripper = field("bool", "status.more_flags.gripper_enabled", "Gripper driver enabled", 16, nil, 0x0010),
    st_more_stop_cause = field("uint16", "status.more_flags.stop_cause", "What ended the last run (issue 31)", base.DEC, stop_cause_names, 0x00e0),
    st_joints_enabled = hex("uint16", "status.joints_enabled", "Joint drivers enabled (bit j = joint j)"),
    st_upload_period = dec("uint32", "status.upload_period_us", "Upload period (us)"),
    st_pwm_clock = dec("uint32", "status.pwm_timer_clock_hz", "PWM timer clock (Hz)"),
    st_max_rate = dec("uint32", "status.max_step_rate_hz", "Max step rate (steps/s)"),
    st_word32 = dec("uint32", "status.offset32", "Offset 32 (u32)"),

    -- DISCOVER_REPLY and NET_SET (PROTOCOL.md, "Finding controllers and setting their address")
    disc_mac = field("ether", "discover.mac", "MAC address"),
    disc_ip = field("ipv4", "discover.ip", "IPv4 address"),
    disc_prefix = dec("uint8", "discover.prefix_len", "Prefix length"),
    disc_gateway = field("ipv4", "discover.gateway", "Gateway"),
    disc_mode = dec("uint8", "discover.addr_mode", "Address mode", addr_mode_names),
    disc_version = field("string", "discover.version", "Protocol version"),
    disc_joints = dec("uint8", "discover.joints", "Joints"),
    disc_state = dec("uint8", "discover.state", "State", state_names),
    disc_owner = dec("uint8", "discover.owner", "Owner state", owner_names),
    disc_owner_ip = field("ipv4", "discover.owner_ip", "Owner address"),
    disc_pending = field("bool", "discover.pending_reset", "New address stored, applied after reset", 8, nil, 0x01),
    net_mode = dec("uint8", "net.addr_mode", "Address mode", addr_mode_names),
    net_ip = field("ipv4", "net.ip", "IPv4 address"),
    net_prefix = dec("uint8", "net.prefix_len", "Prefix length"),
    net_gateway = field("ipv4", "net.gateway", "Gateway"),

    -- what a controller answers to this command (host to controller only)
    verdict = dec("uint8", "verdict", "Controller answers", status_names),

    -- analysis
    response_in = field("framenum", "response_in", "ACK in frame"),
    response_to = field("framenum", "response_to", "ACK to the command in frame"),
    rtt = field("relative_time", "time", "Round trip"),
    retransmission = field("framenum", "retransmission", "Retransmission of frame"),
}
local fields = {}
for _, field in pairs(f) do fields[#fields + 1] = field end
armctl.fields = fields

local e = {
    bad_crc = ProtoExpert.new("armctl.crc.bad", "Bad CRC", expert.group.CHECKSUM, expert.severity.ERROR),
    too_short = ProtoExpert.new("armctl.too_short", "Datagram too short for a frame (3 bytes at least): no reply",
        expert.group.MALFORMED, expert.severity.ERROR),
    bad_length = ProtoExpert.new("armctl.bad_length", "Data length does not fit the tag",
        expert.group.MALFORMED, expert.severity.ERROR),
    unknown_tag = ProtoExpert.new("armctl.unknown_tag", "Unknown tag", expert.group.MALFORMED, expert.severity.ERROR),
    wrong_direction = ProtoExpert.new("armctl.wrong_direction", "Tag sent in the wrong direction",
        expert.group.PROTOCOL, expert.severity.WARN),
    refused = ProtoExpert.new("armctl.ack.refused", "Command refused", expert.group.RESPONSE_CODE, expert.severity.WARN),
    retransmission = ProtoExpert.new("armctl.retransmission.expert", "Retransmission",
        expert.group.SEQUENCE, expert.severity.NOTE),
    invalid_config = ProtoExpert.new("armctl.invalid_config", "Value out of range",
        expert.group.MALFORMED, expert.severity.ERROR),
    invalid_point = ProtoExpert.new("armctl.invalid_point", "Point duration under 1 us",
        expert.group.MALFORMED, expert.severity.ERROR),
    no_ack = ProtoExpert.new("armctl.no_ack", "No ACK seen for this command",
        expert.group.SEQUENCE, expert.severity.NOTE),
}
e.bad_mac = ProtoExpert.new("armctl.bad_mac", "Authentication MAC does not verify",
    expert.group.SECURITY, expert.severity.ERROR)
armctl.experts = { e.bad_crc, e.too_short, e.bad_length, e.unknown_tag, e.wrong_direction,
    e.refused, e.retransmission, e.no_ack, e.invalid_config, e.invalid_point, e.bad_mac }

----------------------------------------------------------------------------------------
-- CRC-8/SMBUS: polynomial 0x07, init 0, no reflection, no final XOR. (Wireshark 4.0 runs
-- Lua 5.2: no bitwise operators, hence the `bit` library.)

local crc_table = {}
for i = 0, 255 do
    local c = i
    for _ = 1, 8 do
        if c >= 0x80 then c = bit.bxor((c * 2) % 256, 0x07) else c = (c * 2) % 256 end
    end
    crc_table[i] = c
end

local function crc8(tvb, len)
    local c = 0
    for i = 0, len - 1 do
        c = crc_table[bit.bxor(c, tvb(i, 1):uint())]
    end
    return c
end

----------------------------------------------------------------------------------------
-- Keyed BLAKE2s-128 (RFC 7693), the envelopes' MAC (PROTOCOL.md section 13). Words are
-- kept as the `bit` library's signed 32-bit numbers; sums are wrapped with bit.tobit.

local B2S_IV = {}
for i, w in ipairs({ 0x6A09E667, 0xBB67AE85, 0x3C6EF372, 0xA54FF53A, 0x510E527F,
    0x9B05688C, 0x1F83D9AB, 0x5BE0CD19 }) do B2S_IV[i] = bit.tobit(w) end
local B2S_SIGMA = {
    { 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15 },
    { 14, 10, 4, 8, 9, 15, 13, 6, 1, 12, 0, 2, 11, 7, 5, 3 },
    { 11, 8, 12, 0, 5, 2, 15, 13, 10, 14, 3, 6, 7, 1, 9, 4 },
    { 7, 9, 3, 1, 13, 12, 11, 14, 2, 6, 5, 10, 4, 0, 15, 8 },
    { 9, 0, 5, 7, 2, 4, 10, 15, 14, 1, 11, 12, 6, 8, 3, 13 },
    { 2, 12, 6, 10, 0, 11, 8, 3, 4, 13, 7, 5, 15, 14, 1, 9 },
    { 12, 5, 1, 15, 14, 13, 4, 10, 0, 7, 6, 3, 9, 2, 8, 11 },
    { 13, 11, 7, 14, 12, 1, 3, 9, 5, 0, 15, 4, 8, 6, 2, 10 },
    { 6, 15, 14, 9, 11, 3, 0, 8, 12, 2, 13, 7, 1, 4, 10, 5 },
    { 10, 2, 8, 4, 7, 6, 1, 5, 15, 11, 9, 14, 3, 12, 13, 0 },
}

local function b2s_g(v, a, b, c, d, x, y)
    v[a] = bit.tobit(v[a] + v[b] + x); v[d] = bit.ror(bit.bxor(v[d], v[a]), 16)
    v[c] = bit.tobit(v[c] + v[d]);     v[b] = bit.ror(bit.bxor(v[b], v[c]), 12)
    v[a] = bit.tobit(v[a] + v[b] + y); v[d] = bit.ror(bit.bxor(v[d], v[a]), 8)
    v[c] = bit.tobit(v[c] + v[d]);     v[b] = bit.ror(bit.bxor(v[b], v[c]), 7)
end

-- Compresses the 64 bytes of `bytes` from index `at` (1-based; missing bytes are zero).
local function b2s_compress(h, bytes, at, t, last)
    local m = {}
    for i = 0, 15 do
        local w = 0
        for k = 3, 0, -1 do w = w * 256 + (bytes[at + 4 * i + k] or 0) end
        m[i] = bit.tobit(w)
    end
    local v = {}
    for i = 1, 8 do v[i] = h[i]; v[i + 8] = B2S_IV[i] end
    v[13] = bit.bxor(v[13], bit.tobit(t % 4294967296))
    v[14] = bit.bxor(v[14], bit.tobit(math.floor(t / 4294967296)))
    if last then v[15] = bit.bnot(v[15]) end
    for r = 1, 10 do
        local s = B2S_SIGMA[r]
        b2s_g(v, 1, 5, 9, 13, m[s[1]], m[s[2]]);   b2s_g(v, 2, 6, 10, 14, m[s[3]], m[s[4]])
        b2s_g(v, 3, 7, 11, 15, m[s[5]], m[s[6]]);  b2s_g(v, 4, 8, 12, 16, m[s[7]], m[s[8]])
        b2s_g(v, 1, 6, 11, 16, m[s[9]], m[s[10]]); b2s_g(v, 2, 7, 12, 13, m[s[11]], m[s[12]])
        b2s_g(v, 3, 8, 9, 14, m[s[13]], m[s[14]]); b2s_g(v, 4, 5, 10, 15, m[s[15]], m[s[16]])
    end
    for i = 1, 8 do h[i] = bit.bxor(h[i], v[i], v[i + 8]) end
end

local function le_word(bytes, at)
    local w = 0
    for k = 3, 0, -1 do w = w * 256 + bytes[at + k] end
    return bit.tobit(w)
end

-- BLAKE2s with a 32-byte key, 16-byte output and an 8-byte personalisation, of `msg`
-- (a table of byte values); returns the 16 bytes as a table.
local function blake2s_mac(key, persona, msg)
    local h = {}
    for i = 1, 8 do h[i] = B2S_IV[i] end
    h[1] = bit.bxor(h[1], 0x01012010)  -- fanout 1, depth 1, key 32 bytes, digest 16 bytes
    h[7] = bit.bxor(h[7], le_word(persona, 1))
    h[8] = bit.bxor(h[8], le_word(persona, 5))
    local bytes = {}
    for i = 1, 32 do bytes[i] = key[i] end
    for i = 33, 64 do bytes[i] = 0 end
    for i = 1, #msg do bytes[64 + i] = msg[i] end
    local total = #bytes
    local at = 1
    while total - (at - 1) > 64 do
        b2s_compress(h, bytes, at, at + 63, false)
        at = at + 64
    end
    b2s_compress(h, bytes, at, total, true)
    local out = {}
    for i = 0, 15 do
        out[i + 1] = bit.band(bit.rshift(h[math.floor(i / 4) + 1], 8 * (i % 4)), 0xff)
    end
    return out
end

local function key_bytes()
    local hex = (armctl.prefs.key or ""):gsub("%s", "")
    if #hex ~= 64 or hex:find("[^%x]") then return nil end
    local key = {}
    for i = 1, 32 do key[i] = tonumber(hex:sub(2 * i - 1, 2 * i), 16) end
    return key
end

local function range_bytes(range, out)
    out = out or {}
    for i = 0, range:len() - 1 do out[#out + 1] = range(i, 1):uint() end
    return out
end

local PERSONA_TO_CONTROLLER = { 0x61, 0x72, 0x6d, 0x48, 0x32, 0x43, 0x30, 0x31 } -- "armH2C01"
local PERSONA_TO_HOST = { 0x61, 0x72, 0x6d, 0x43, 0x32, 0x48, 0x30, 0x31 }       -- "armC2H01"

local epochs = {}        -- controller "ip:port" -> the 8 epoch bytes of its last HELLO_REPLY
local hello_epoch = nil  -- set by the HELLO_REPLY dissector for the envelope around it

----------------------------------------------------------------------------------------
-- Pairing and retransmissions (filled on the first pass, shown on every pass)

local analysis = {}     -- frame number -> { response_in, response_to, rtt, retransmission_of }
local commands = {}     -- "host ip:port|seq|tag" -> { crc, copies = { {frame, time}, ... } }:
                        -- the copies not yet answered, oldest first, and the latest one
local first_copy = {}   -- "host ip:port|seq|tag|crc" -> frame number of the first copy

function armctl.init()
    epochs = {}
    analysis = {}
    commands = {}
    first_copy = {}
end

local function frame_info(number)
    local info = analysis[number]
    if not info then
        info = {}
        analysis[number] = info
    end
    return info
end

----------------------------------------------------------------------------------------
-- Field helpers

local function add_le(tree, field, range, signed)
    if signed then return tree:add_le(field, range, range:le_int()) end
    return tree:add_le(field, range)
end

local function add_positions(tree, field, data, at)
    local positions = {}
    local sub = tree:add(armctl, data(at, 32), "Positions (steps)")
    for j = 0, 7 do
        local v = data(at + 4 * j, 4):le_int()
        sub:add_le(field, data(at + 4 * j, 4), v):prepend_text("Joint " .. j .. " ")
        positions[#positions + 1] = tostring(v)
    end
    sub:append_text(": " .. table.concat(positions, ", "))
end

local function dissect_point(tree, data, at, index)
    local point = tree:add(f.point, data(at, 116))
    local duration = data(at, 4):le_int()
    point:set_text(string.format("Point %d: %d us", index, duration))
    point:add_le(f.point_duration, data(at, 4), duration)
    add_positions(point, f.point_position, data, at + 84)
    local hints = point:add(armctl, data(at + 4, 80), "Timer hints (not used by the controller)")
    -- Four arrays of 8 signed values: { field, offset, width }.
    for _, array in ipairs({ { f.point_full, 4, 2 }, { f.point_rest, 20, 2 },
        { f.point_nperiod, 36, 2 }, { f.point_period, 52, 4 } }) do
        local field, offset, width = array[1], array[2], array[3]
        for j = 0, 7 do
            local range = data(at + offset + width * j, width)
            hints:add_le(field, range, range:le_int())
        end
    end
end

local function dissect_location(tree, data)
    add_positions(tree, f.location_position, data, 0)
    tree:add(f.location_state, data(32, 1))
end

local function dissect_uart(tree, data, manual_form)
    local skip = manual_form and 4 or 0
    tree:add_le(f.uart_baud, data(0, 4))
    tree:add_le(f.uart_word, data(4, 4))
    tree:add_le(f.uart_stop, data(8, 4))
    tree:add_le(f.uart_parity, data(12, 4))
    if manual_form then tree:add_le(f.uart_parity2, data(16, 4)) end
    tree:add_le(f.uart_mode, data(16 + skip, 4))
    tree:add_le(f.uart_flow, data(20 + skip, 4))
    tree:add_le(f.uart_over, data(24 + skip, 4))
end

local function dissect_status_report(tree, data)
    local v = data(0, 3)
    tree:add(f.st_version, v, string.format("%d.%d.%d", v(0, 1):uint(), v(1, 1):uint(), v(2, 1):uint()))
    tree:add(f.st_joints, data(3, 1))
    tree:add(f.st_state, data(4, 1))
    local flags = tree:add(f.st_flags, data(5, 1))
    for _, bit in ipairs({ f.st_flag_reports, f.st_flag_drivers, f.st_flag_serial, f.st_flag_pin0,
        f.st_flag_pin1, f.st_flag_underrun, f.st_flag_pwm, f.st_flag_stopped }) do
        flags:add(bit, data(5, 1))
    end
    -- u16 fields from offset 6, then u32 fields from offset 20.
    for i, field in ipairs({ f.st_window, f.st_buffered, f.st_expected, f.st_received,
        f.st_executed, f.st_capacity }) do
        tree:add_le(field, data(4 + 2 * i, 2))
    end
    local more = tree:add_le(f.st_more_flags, data(18, 2))
    for _, bit in ipairs({ f.st_more_dropped, f.st_more_estop_open, f.st_more_estop_latched,
        f.st_more_enables, f.st_more_gripper, f.st_more_stop_cause }) do
        more:add_le(bit, data(18, 2))
    end
    -- Bits 8-15: joints 0-7, meaningful only with bit 3 (an older controller sends 0).
    if bit.band(data(18, 2):le_uint(), 0x0008) ~= 0 then
        more:add(f.st_joints_enabled, data(19, 1), data(19, 1):uint())
    end
    for i, field in ipairs({ f.st_upload_period, f.st_pwm_clock, f.st_max_rate, f.st_word32 }) do
        tree:add_le(field, data(16 + 4 * i, 4))
    end
end

local function dissect_discover_reply(tree, data)
    tree:add(f.disc_mac, data(0, 6))
    tree:add(f.disc_ip, data(6, 4))
    tree:add(f.disc_prefix, data(10, 1))
    tree:add(f.disc_gateway, data(11, 4))
    tree:add(f.disc_mode, data(15, 1))
    local v = data(16, 3)
    tree:add(f.disc_version, v, string.format("%d.%d.%d", v(0, 1):uint(), v(1, 1):uint(), v(2, 1):uint()))
    tree:add(f.disc_joints, data(19, 1))
    tree:add(f.disc_state, data(20, 1))
    tree:add(f.disc_owner, data(21, 1))
    tree:add(f.disc_owner_ip, data(22, 4))
    tree:add(f.disc_pending, data(26, 1))
end

local function dissect_net_set(tree, data)
    tree:add(f.net_mode, data(0, 1))
    tree:add(f.net_ip, data(1, 4))
    tree:add(f.net_prefix, data(5, 1))
    tree:add(f.net_gateway, data(6, 4))
end

-- Each returns a short summary for the Info column, or nil plus an error for a bad length.
-- `len` is the data length, `data` the data range (nil when empty).

-- The status a controller answers to the frame being dissected (PROTOCOL.md, the order of
-- checks at the end of "Ordering, retransmission and duplicates"):
-- the first failure found, or OK.
local verdict = 0

local function refuse(status)
    if verdict == 0 then verdict = status end
end

local function out_of_range(tree, what)
    refuse(11)
    tree:add_proto_expert_info(e.invalid_config, what)
end

local function length_error(tree, range, expected, found)
    refuse(3)
    tree:add_proto_expert_info(e.bad_length,
        string.format("Data length %d, expected %s", found, expected))
    return nil
end

-- JOINT_DESC_SET's data and the JOINT_DESC report's (issue 31): joint, 3 reserved, name
-- (16 bytes, UTF-8, zero padded), unit, 3 reserved, zero offset i32, scale f64.
local function dissect_joint_desc(tree, data)
    local joint, unit = data(0, 1):uint(), data(20, 1):uint()
    tree:add(f.limits_joint, data(0, 1))
    tree:add(f.desc_name, data(4, 16))
    tree:add(f.desc_unit, data(20, 1))
    tree:add_le(f.desc_zero, data(24, 4), data(24, 4):le_int())
    tree:add_le(f.desc_scale, data(28, 8))
    if joint > 7 then out_of_range(tree, "JOINT_DESC needs a joint of 0-7") end
    if unit > 3 then out_of_range(tree, "JOINT_DESC unit must be 0-3") end
    return string.format("joint %d \"%s\": %s, %g steps per unit", joint,
        data(4, 16):stringz(), desc_unit_names[unit] or "?", data(28, 8):le_float())
end

-- HOMING_SET's data and the HOMING report's (issue 33): joint, flags, order, reserved, seek
-- rate, approach rate, back-off, max travel (u32 each), offset (i32).
local function dissect_homing(tree, data)
    local joint, flags = data(0, 1):uint(), data(1, 1):uint()
    tree:add(f.homing_joint, data(0, 1))
    tree:add(f.homing_flags, data(1, 1))
    tree:add(f.homing_order, data(2, 1))
    tree:add_le(f.homing_seek, data(4, 4))
    tree:add_le(f.homing_approach, data(8, 4))
    tree:add_le(f.homing_backoff, data(12, 4))
    tree:add_le(f.homing_travel, data(16, 4))
    tree:add_le(f.homing_offset, data(20, 4), data(20, 4):le_int())
    if joint > 7 then out_of_range(tree, "HOMING_SET needs a joint of 0-7") end
    if flags > 7 then out_of_range(tree, "HOMING_SET flags may only use bits 0-2") end
    if bit.band(flags, 1) ~= 0 and (data(4, 4):le_uint() == 0 or data(8, 4):le_uint() == 0
        or data(12, 4):le_uint() == 0 or data(16, 4):le_uint() == 0) then
        out_of_range(tree, "HOMING_SET needs non-zero rates, back-off and travel on an enabled joint")
    end
    if bit.band(flags, 1) == 0 then return string.format("joint %d: not homed", joint) end
    local side = "min"
    if bit.band(flags, 2) ~= 0 then side = "max" end
    return string.format("joint %d: towards %s at %d steps/s, offset %d", joint, side,
        data(4, 4):le_uint(), data(20, 4):le_int())
end

local host_dissectors = {
    [0x00] = function(tree, data, len)
        if len ~= 2 then return length_error(tree, data, "2", len) end
        tree:add(f.new_count, data(0, 2))
        if data(0, 2):uint() == 0 then out_of_range(tree, "NEW point count must be 1..65535") end
        return "count " .. data(0, 2):uint()
    end,
    [0x01] = function(tree, data, len)
        if len == 0 or len % 116 ~= 0 or len > 12 * 116 then
            return length_error(tree, data, "1 to 12 records of 116 bytes", len)
        end
        local n = math.floor(len / 116)
        tree:add(f.points, data(0, len), n)
        local total = 0
        for i = 0, n - 1 do
            dissect_point(tree, data, i * 116, i)
            local duration = data(i * 116, 4):le_int()
            if duration < 1 then
                refuse(7)
                tree:add_proto_expert_info(e.invalid_point, string.format("Point %d has a duration of %d us", i, duration))
            end
            total = total + duration
        end
        return string.format("%d point%s, %d us", n, n == 1 and "" or "s", total)
    end,
    [0x06] = function(tree, data, len)
        if len ~= 16 then return length_error(tree, data, "16", len) end
        tree:add_le(f.pwm_psc, data(0, 4))
        tree:add_le(f.pwm_arr, data(4, 4))
        tree:add_le(f.pwm_ccr1, data(8, 4))
        local pulses = data(12, 4):le_int()
        tree:add_le(f.pwm_pulse_count, data(12, 4), pulses)
        local psc, arr, ccr1 = data(0, 4):le_uint(), data(4, 4):le_uint(), data(8, 4):le_uint()
        if psc > 0xFFFF then out_of_range(tree, "PWM PSC must fit 16 bits") end
        if arr > 0xFFFF then out_of_range(tree, "PWM ARR must fit 16 bits") end
        if ccr1 > arr then out_of_range(tree, "PWM CCR1 must not exceed ARR") end
        return pulses == 0 and "servo" or ("stepper, " .. pulses .. " pulses")
    end,
    [0x08] = function(tree, data, len)
        if len ~= 28 and len ~= 32 then return length_error(tree, data, "28 or 32", len) end
        dissect_uart(tree, data, len == 32)
        local baud = data(0, 4):le_uint()
        if baud < 300 or baud > 4000000 then out_of_range(tree, "baud rate must be 300..4000000") end
        return data(0, 4):le_uint() .. " baud"
    end,
    [0x0a] = function(tree, data, len)
        if len < 1 or len > 255 then return length_error(tree, data, "1 to 255", len) end
        tree:add(f.usart_data, data(0, len))
        return len .. " bytes"
    end,
    [0x10] = function(tree, data, len)
        if len == 0 then return "every driver" end
        if len ~= 2 then return length_error(tree, data, "0 or 2", len) end
        tree:add(f.enable_mask, data(0, 2))
        if data(0, 2):uint() > 0x01FF then out_of_range(tree, "enable mask may only use bits 0-8") end
        return string.format("mask 0x%04x", data(0, 2):uint())
    end,
    [0x18] = function(tree, data, len)
        if len ~= 3 then return length_error(tree, data, "3", len) end
        tree:add_le(f.enable_mask, data(0, 2))
        tree:add(f.enable_action, data(2, 1))
        local mask, action = data(0, 2):le_uint(), data(2, 1):uint()
        if mask > 0x01FF then out_of_range(tree, "enable mask may only use bits 0-8") end
        if action > 1 then out_of_range(tree, "SET_ENABLE action must be 0 (disable) or 1 (enable)") end
        return string.format("%s mask 0x%04x", action == 1 and "enable" or "disable", mask)
    end,
    -- ACCEL_SET (issue 31): joint, 3 reserved, max_accel_steps_s2.
    [0x1e] = function(tree, data, len)
        if len ~= 8 then return length_error(tree, data, "8", len) end
        tree:add(f.limits_joint, data(0, 1))
        tree:add_le(f.limits_accel, data(4, 4))
        if data(0, 1):uint() > 7 then out_of_range(tree, "ACCEL_SET needs a joint of 0-7") end
        return string.format("joint %d: %d steps/s²", data(0, 1):uint(), data(4, 4):le_uint())
    end,
    -- JOINT_DESC_SET (issue 31): joint, 3 reserved, the description.
    [0x1f] = function(tree, data, len)
        if len ~= 36 then return length_error(tree, data, "36", len) end
        return dissect_joint_desc(tree, data)
    end,
    -- OVERRIDE (issue 32): the percent, 1..200.
    [0x29] = function(tree, data, len)
        if len ~= 1 then return length_error(tree, data, "1", len) end
        tree:add(f.override_percent, data(0, 1))
        local percent = data(0, 1):uint()
        if percent < 1 or percent > 200 then out_of_range(tree, "OVERRIDE percent must be 1..200") end
        return percent .. " %"
    end,
    -- ESTOP_CATEGORY (issue 32): the category, 0 or 1.
    [0x2b] = function(tree, data, len)
        if len ~= 1 then return length_error(tree, data, "1", len) end
        tree:add(f.estop_category, data(0, 1))
        local category = data(0, 1):uint()
        if category > 1 then out_of_range(tree, "ESTOP_CATEGORY must be 0 or 1") end
        return "category " .. category
    end,
    -- JOINT_DESC_GET (issue 31): the joint.
    [0x23] = function(tree, data, len)
        if len ~= 1 then return length_error(tree, data, "1", len) end
        tree:add(f.limits_joint, data(0, 1))
        if data(0, 1):uint() > 7 then out_of_range(tree, "JOINT_DESC_GET needs a joint of 0-7") end
        return string.format("joint %d", data(0, 1):uint())
    end,
    -- LIMITS_GET: no data (old hosts), or the request byte 0x01 (issue 31).
    [0x1b] = function(tree, data, len)
        if len == 0 then return "" end
        if len ~= 1 then return length_error(tree, data, "0 or 1", len) end
        tree:add(f.limits_ask, data(0, 1))
        if data(0, 1):uint() ~= 1 then out_of_range(tree, "LIMITS_GET request byte must be 0x01") end
        return "with the accelerations"
    end,
    [0x1a] = function(tree, data, len)
        if len ~= 16 then return length_error(tree, data, "16", len) end
        tree:add(f.limits_joint, data(0, 1))
        local min, max = data(4, 4):le_int(), data(8, 4):le_int()
        tree:add_le(f.limits_min, data(4, 4), min)
        tree:add_le(f.limits_max, data(8, 4), max)
        tree:add_le(f.limits_rate, data(12, 4))
        if data(0, 1):uint() > 7 then out_of_range(tree, "LIMITS_SET needs a joint of 0-7") end
        if min > max then out_of_range(tree, "LIMITS_SET: min above max") end
        return string.format("joint %d: %d..%d steps, %d steps/s", data(0, 1):uint(), min, max,
            data(12, 4):le_uint())
    end,
    [0x12] = function(tree, data, len)
        if len ~= 1 then return length_error(tree, data, "1", len) end
        tree:add(f.joints, data(0, 1))
        local joints = data(0, 1):uint()
        if joints < 1 or joints > 8 then out_of_range(tree, "joint count must be 1..8") end
        return data(0, 1):uint() .. " joints"
    end,
    [0x13] = function(tree, data, len)
        if len ~= 36 and len ~= 33 then return length_error(tree, data, "36 or 33", len) end
        dissect_location(tree, data)
        return ""
    end,
    [0x16] = function(tree, data, len)
        if len ~= 4 then return length_error(tree, data, "4", len) end
        tree:add_le(f.upload_period, data(0, 4))
        local period = data(0, 4):le_uint()
        if period < 1000 or period > 1000000 then out_of_range(tree, "upload period must be 1000..1000000 us") end
        return data(0, 4):le_uint() .. " us"
    end,
    [0x21] = function(tree, data, len)
        if len ~= 10 then return length_error(tree, data, "10", len) end
        dissect_net_set(tree, data)
        if data(0, 1):uint() > 1 then out_of_range(tree, "address mode must be 0 (static) or 1 (DHCP)") end
        if data(0, 1):uint() == 1 then return "DHCP" end
        return string.format("%s/%d", tostring(data(1, 4):ipv4()), data(5, 1):uint())
    end,
}
host_dissectors[0x51] = function(tree, data, len)
    if len ~= 16 then return length_error(tree, data, "16", len) end
    tree:add(f.hello_nonce, data(0, 16))
    return ""
end
host_dissectors[0x52] = function(tree, data, len)
    if len == 0 then return "clear the key" end
    if len ~= 32 then return length_error(tree, data, "0 or 32", len) end
    tree:add(f.set_key, data(0, 32))
    return "set a key"
end
host_dissectors[0x2d] = function(tree, data, len)
    if len ~= 24 then return length_error(tree, data, "24", len) end
    return dissect_homing(tree, data)
end
host_dissectors[0x2e] = function(tree, data, len)
    if len ~= 1 then return length_error(tree, data, "1", len) end
    tree:add(f.homing_joint, data(0, 1))
    if data(0, 1):uint() > 7 then out_of_range(tree, "HOMING_GET needs a joint of 0-7") end
    return "joint " .. data(0, 1):uint()
end
-- Commands without data.
for _, tag in ipairs({ 0x02, 0x04, 0x05, 0x07, 0x09, 0x0c, 0x0d, 0x0e, 0x0f, 0x11, 0x17, 0x19, 0x20, 0x25,
    0x27, 0x28, 0x2c }) do
    host_dissectors[tag] = function(tree, data, len)
        if len ~= 0 then return length_error(tree, data, "0", len) end
        return ""
    end
end
-- STATUS: no data (old hosts), or the request byte (issue 23): bit 0 a LOCATION too, bit 1
-- look only; bit 2 a STOP_CAUSE report too (issue 31); bit 3 an RX_COUNTERS report too
-- (issue 30); bit 4 a MOTION report too (issue 32); bit 6 a DIAG report too (issue 34).
-- The reports follow the STATUS in that order: LOCATION, STOP_CAUSE, RX_COUNTERS, MOTION, DIAG.
host_dissectors[0x15] = function(tree, data, len)
    if len == 0 then return "" end
    if len ~= 1 then return length_error(tree, data, "0 or 1", len) end
    local ask = tree:add(f.status_ask, data(0, 1))
    ask:add(f.status_ask_location, data(0, 1))
    ask:add(f.status_ask_look, data(0, 1))
    ask:add(f.status_ask_stop, data(0, 1))
    ask:add(f.status_ask_counters, data(0, 1))
    ask:add(f.status_ask_motion, data(0, 1))
    ask:add(f.status_ask_switches, data(0, 1))
    ask:add(f.status_ask_diag, data(0, 1))
    local b = data(0, 1):uint()
    if bit.band(b, 0x80) ~= 0 then out_of_range(tree, "STATUS request byte may only use bits 0-6") end
    local parts = {}
    if bit.band(b, 1) ~= 0 then parts[#parts + 1] = "with LOCATION" end
    if bit.band(b, 2) ~= 0 then parts[#parts + 1] = "look only" end
    if bit.band(b, 4) ~= 0 then parts[#parts + 1] = "with STOP_CAUSE" end
    if bit.band(b, 8) ~= 0 then parts[#parts + 1] = "with RX_COUNTERS" end
    if bit.band(b, 16) ~= 0 then parts[#parts + 1] = "with MOTION" end
    if bit.band(b, 0x40) ~= 0 then parts[#parts + 1] = "with DIAG" end
    if bit.band(b, 0x20) ~= 0 then parts[#parts + 1] = "with SWITCHES" end
    return table.concat(parts, ", ")
end
-- STOPPED: any data is ignored by the controller, which stops all the same (PROTOCOL.md
-- section 4, issue 18): shown, not flagged as a length error.
host_dissectors[0x03] = function(tree, data, len)
    if len > 0 then return string.format("(%d data bytes, ignored)", len) end
    return ""
end

local controller_dissectors = {
    [0x14] = function(tree, data, len)
        if len ~= 8 then return length_error(tree, data, "8", len) end
        local acked = data(0, 1):uint()
        local status = data(1, 1):uint()
        tree:add(f.ack_acked_tag, data(0, 1))
        local item = tree:add(f.ack_status, data(1, 1))
        tree:add(f.ack_state, data(2, 1))
        tree:add(f.ack_next_seq, data(3, 1))
        tree:add_le(f.ack_buffered, data(4, 2))
        tree:add_le(f.ack_free, data(6, 2))
        if status ~= 0 then
            item:add_proto_expert_info(e.refused, string.format("%s refused: %s",
                tag_names[acked] or string.format("0x%02x", acked), status_names[status] or tostring(status)))
        end
        return string.format("%s %s", tag_names[acked] or string.format("0x%02x", acked),
            status_names[status] or tostring(status))
    end,
    [0x13] = function(tree, data, len)
        if len ~= 36 and len ~= 33 then return length_error(tree, data, "36 or 33", len) end
        dissect_location(tree, data)
        return state_names[data(32, 1):uint()] or "?"
    end,
    [0x0b] = function(tree, data, len)
        if len ~= 257 then return length_error(tree, data, "257", len) end
        local n = data(0, 1):uint()
        tree:add(f.usart_len, data(0, 1))
        if n > 0 then tree:add(f.usart_data, data(1, n)) end
        return n .. " bytes"
    end,
    [0x1c] = function(tree, data, len)
        if len ~= 112 and len ~= 144 then return length_error(tree, data, "112 or 144", len) end
        -- 144: each joint's max acceleration after the 112 bytes (issue 31).
        if len == 144 then
            for j = 0, 7 do
                tree:add_le(f.limits_accel, data(112 + 4 * j, 4))
            end
        end
        for j = 0, 7 do
            local at = 12 * j
            local sub = tree:add(armctl, data(at, 12), string.format("Joint %d: %d..%d steps, %d steps/s",
                j, data(at, 4):le_int(), data(at + 4, 4):le_int(), data(at + 8, 4):le_uint()))
            sub:add_le(f.limits_min, data(at, 4), data(at, 4):le_int())
            sub:add_le(f.limits_max, data(at + 4, 4), data(at + 4, 4):le_int())
            sub:add_le(f.limits_rate, data(at + 8, 4))
        end
        local r = tree:add(armctl, data(96, 16), "Last refusal")
        r:add(f.refusal_seq, data(96, 1))
        r:add(f.refusal_tag, data(97, 1))
        r:add(f.refusal_point, data(98, 1))
        r:add(f.refusal_joint, data(99, 1))
        r:add(f.refusal_reason, data(100, 1))
        r:add_le(f.refusal_value, data(104, 4), data(104, 4):le_int())
        r:add_le(f.refusal_limit, data(108, 4), data(108, 4):le_int())
        return refusal_names[data(100, 1):uint()] or "?"
    end,
    [0x1d] = function(tree, data, len)
        if len ~= 12 then return length_error(tree, data, "12", len) end
        local cause = data(0, 1):uint()
        tree:add(f.stop_cause, data(0, 1))
        tree:add(f.stop_detail, data(1, 1))
        tree:add(f.stop_ip, data(4, 4))
        tree:add_le(f.stop_port, data(8, 2))
        local name = stop_cause_names[cause] or "?"
        if cause == 2 then
            return string.format("%s from %s:%d", name, tostring(data(4, 4):ipv4()), data(8, 2):le_uint())
        end
        if cause == 5 then return string.format("%s (joint %d)", name, data(1, 1):uint()) end
        return name
    end,
    [0x15] = function(tree, data, len)
        if len ~= 36 then return length_error(tree, data, "36", len) end
        dissect_status_report(tree, data)
        return state_names[data(4, 1):uint()] or "?"
    end,
    -- HOMING (issue 33): HOMING_SET's data.
    [0x2f] = function(tree, data, len)
        if len ~= 24 then return length_error(tree, data, "24", len) end
        return dissect_homing(tree, data)
    end,
    -- SWITCHES (issue 33): the homing cycle and the switch inputs.
    [0x30] = function(tree, data, len)
        if len ~= 8 then return length_error(tree, data, "8", len) end
        tree:add(f.sw_phase, data(0, 1))
        tree:add(f.sw_joint, data(1, 1))
        tree:add(f.sw_error, data(2, 1))
        tree:add(f.sw_homed, data(3, 1))
        tree:add(f.sw_home, data(4, 1))
        tree:add(f.sw_min, data(5, 1))
        tree:add(f.sw_max, data(6, 1))
        tree:add(f.sw_latched, data(7, 1))
        local text = homing_phase_names[data(0, 1):uint()] or "?"
        if data(0, 1):uint() == 3 then
            text = string.format("%s: joint %d, %s", text, data(1, 1):uint(),
                homing_error_names[data(2, 1):uint()] or "?")
        end
        local latched = data(7, 1):uint()
        if latched ~= 0xff then
            local side = "min"
            if bit.band(latched, 0x80) ~= 0 then side = "max" end
            text = string.format("%s; latched on joint %d %s limit", text, bit.band(latched, 0x7f), side)
        end
        return text
    end,
    -- JOINT_DESC (issue 31): JOINT_DESC_SET's data.
    [0x26] = function(tree, data, len)
        if len ~= 36 then return length_error(tree, data, "36", len) end
        return dissect_joint_desc(tree, data)
    end,
    -- MOTION (issue 32): factor, flags, rate (u16 LE, 0.1 %), last controlled stop,
    -- refused joint and limit, the e-stop category.
    [0x2a] = function(tree, data, len)
        if len ~= 8 then return length_error(tree, data, "8", len) end
        tree:add(f.motion_factor, data(0, 1))
        local flags = tree:add(f.motion_flags, data(1, 1))
        flags:add(f.motion_held, data(1, 1))
        flags:add(f.motion_at_rest, data(1, 1))
        flags:add(f.motion_ramping, data(1, 1))
        flags:add(f.motion_underrun, data(1, 1))
        flags:add(f.motion_door_open, data(1, 1))
        flags:add(f.motion_estop_ramp, data(1, 1))
        tree:add_le(f.motion_rate, data(2, 2))
        tree:add(f.motion_last_stop, data(4, 1))
        tree:add(f.motion_refused_joint, data(5, 1))
        tree:add(f.motion_refused_limit, data(6, 1))
        tree:add(f.estop_category, data(7, 1))
        local held = bit.band(data(1, 1):uint(), 1) ~= 0 and ", held" or ""
        return string.format("%d %%%s, rate %.1f %%", data(0, 1):uint(), held,
            data(2, 2):le_uint() / 10)
    end,
    [0x53] = function(tree, data, len)
        if len ~= 28 then return length_error(tree, data, "28", len) end
        tree:add(f.hello_nonce, data(0, 16))
        tree:add_le(f.hello_epoch, data(16, 8))
        tree:add_le(f.auth_session, data(24, 4))
        hello_epoch = range_bytes(data(16, 8))
        return string.format("session %d", data(24, 4):le_uint())
    end,
    [0x22] = function(tree, data, len)
        if len ~= 27 then return length_error(tree, data, "27", len) end
        dissect_discover_reply(tree, data)
        return tostring(data(6, 4):ipv4())
    end,
    [0x24] = function(tree, data, len)
        if len ~= 24 then return length_error(tree, data, "24", len) end
        tree:add_le(f.rx_ring_dropped, data(0, 4))
        tree:add_le(f.rx_ring_full, data(4, 4))
        tree:add_le(f.rx_interrupt_stops, data(8, 4))
        tree:add_le(f.rx_shed, data(12, 4))
        tree:add_le(f.rx_inbox_dropped, data(16, 4))
        tree:add_le(f.rx_group_ignored, data(20, 4))
        return string.format("ring dropped %d", data(0, 4):le_uint())
    end,
    -- DIAG (issue 34): the board's own timing; clocks of 0: not measured.
    [0x32] = function(tree, data, len)
        if len ~= 36 then return length_error(tree, data, "36", len) end
        tree:add_le(f.diag_cpu_hz, data(0, 4))
        tree:add_le(f.diag_masked_max, data(4, 4))
        tree:add_le(f.diag_masked_opener, data(8, 4))
        tree:add_le(f.diag_masked_spans, data(12, 4))
        tree:add_le(f.diag_step_hz, data(16, 4))
        tree:add_le(f.diag_dir_late, data(20, 4))
        tree:add_le(f.diag_dir_writes, data(24, 4))
        tree:add_le(f.diag_dma_slack, data(28, 4))
        tree:add_le(f.diag_dma_refills, data(32, 4))
        local cpu_hz = data(0, 4):le_uint()
        if cpu_hz == 0 then return "masked spans not measured" end
        return string.format("masked max %d cycles", data(4, 4):le_uint())
    end,
}

----------------------------------------------------------------------------------------
-- The dissector

local function analyse(pinfo, to_controller, seq, tag, crc, data, len)
    if pinfo.visited then return end
    local host_key
    if to_controller then
        host_key = tostring(pinfo.src) .. ":" .. pinfo.src_port
    else
        host_key = tostring(pinfo.dst) .. ":" .. pinfo.dst_port
    end
    if to_controller then
        local key = host_key .. "|" .. seq .. "|" .. tag
        local copy_key = key .. "|" .. crc
        local first = first_copy[copy_key]
        if first and first ~= pinfo.number then
            frame_info(pinfo.number).retransmission_of = first
        else
            first_copy[copy_key] = pinfo.number
        end
        -- Copies with the same bytes queue up: the controller answers each in the order it
        -- got them, so a resend's ACK goes to the resend, not to the first copy. Other bytes
        -- under the same seq and tag (seq wrapped) are a new command: forget the old copies.
        local pending = commands[key]
        if not pending or pending.crc ~= crc then
            pending = { crc = crc, copies = {} }
            commands[key] = pending
        end
        local copy = { frame = pinfo.number, time = pinfo.abs_ts }
        table.insert(pending.copies, copy)
        pending.latest = copy
    elseif (tag == 0x14 and len == 8) or tag == 0x22 then
        -- An ACK answers the tag it names; a DISCOVER_REPLY answers DISCOVER.
        local answered = tag == 0x22 and 0x20 or data(0, 1):uint()
        local key = host_key .. "|" .. seq .. "|" .. answered
        local pending = commands[key]
        local command
        if pending then
            -- The oldest unanswered copy; an ACK beyond the copies seen (its command was not
            -- captured) goes to the latest.
            command = table.remove(pending.copies, 1) or pending.latest
        end
        if command then
            local info = frame_info(pinfo.number)
            info.response_to = command.frame
            info.rtt = pinfo.abs_ts - command.time
            local cmd_info = frame_info(command.frame)
            if not cmd_info.response_in then cmd_info.response_in = pinfo.number end
        end
    end
end

local last_info = ""

-- An AUTH envelope (PROTOCOL.md section 13): its fields, the MAC checked with the key of
-- the preferences and the controller's epoch, and the inner frame dissected as a frame.
local function dissect_auth(tvb, pinfo, root, to_controller, len)
    if len < 34 then
        root:add_proto_expert_info(e.bad_length, "AUTH envelope shorter than 34 bytes")
        return nil
    end
    root:add_le(f.auth_session, tvb(2, 4))
    root:add_le(f.auth_counter, tvb(6, 8))
    local inner_len = len - 31
    local inner_item = root:add(f.auth_inner, tvb(14, inner_len))
    local mac_item = root:add(f.auth_mac, tvb(len - 17, 16))
    hello_epoch = nil
    armctl.dissector(tvb(14, inner_len):tvb(), pinfo, inner_item)
    local inner_info = last_info
    local controller = to_controller and (tostring(pinfo.dst) .. ":" .. pinfo.dst_port)
        or (tostring(pinfo.src) .. ":" .. pinfo.src_port)
    if hello_epoch and not pinfo.visited then epochs[controller] = hello_epoch end
    local epoch = hello_epoch or epochs[controller]
    local key = key_bytes()
    local status = 2
    if key and epoch then
        local msg = {}
        for i = 1, 8 do msg[i] = epoch[i] end
        range_bytes(tvb(0, len - 17), msg)
        local mac = blake2s_mac(key, to_controller and PERSONA_TO_CONTROLLER or PERSONA_TO_HOST, msg)
        status = 1
        for i = 1, 16 do
            if mac[i] ~= tvb(len - 17 + i - 1, 1):uint() then status = 0 end
        end
    end
    mac_item:add(f.auth_mac_status, tvb(len - 17, 16), status):set_generated()
    if status == 0 then
        mac_item:add_proto_expert_info(e.bad_mac, "MAC does not verify with the key of the preferences")
    end
    local verdict_text = ({ [0] = "MAC BAD", [1] = "MAC ok", [2] = "MAC unverified" })[status]
    return string.format("[%s] %s", verdict_text, inner_info)
end

local function show_analysis(tree, pinfo, to_controller)
    local info = analysis[pinfo.number]
    if to_controller then
        if info and info.response_in then
            tree:add(f.response_in, info.response_in):set_generated()
        end
        if info and info.retransmission_of then
            local item = tree:add(f.retransmission, info.retransmission_of)
            item:set_generated()
            item:add_proto_expert_info(e.retransmission,
                "Retransmission of frame " .. info.retransmission_of)
        end
    elseif info and info.response_to then
        tree:add(f.response_to, info.response_to):set_generated()
        local secs = math.floor(info.rtt)
        local rtt = NSTime.new(secs, math.floor((info.rtt - secs) * 1e9 + 0.5))
        tree:add(f.rtt, rtt):set_generated()
    end
end

function armctl.dissector(tvb, pinfo, tree)
    local len = tvb:len()
    if len == 0 then return 0 end
    -- The controller's port: the one the UDP port table matched (the preference, or a
    -- port chosen with Decode As, e.g. a simulator on another port).
    local port = armctl.prefs.port
    if pinfo.match_uint == pinfo.src_port or pinfo.match_uint == pinfo.dst_port then
        port = pinfo.match_uint
    end
    local to_controller = pinfo.dst_port == port or pinfo.src_port ~= port
    pinfo.cols.protocol = armctl.name:upper()
    local root = tree:add(armctl, tvb(), "Arm controller protocol")
    root:add(f.direction, to_controller and 0 or 1):set_generated()
    if len < 3 then
        root:add_proto_expert_info(e.too_short)
        pinfo.cols.info = string.format("%d-byte datagram: too short for a frame", len)
        return len
    end

    local seq = tvb(0, 1):uint()
    local tag = tvb(1, 1):uint()
    local data_len = len - 3
    local data = data_len > 0 and tvb(2, data_len) or nil
    local names = to_controller and host_names or controller_names
    local name = names[tag] or tag_names[tag] or string.format("unknown tag 0x%02x", tag)

    root:add(f.seq, tvb(0, 1))
    local tag_item = root:add(f.tag, tvb(1, 1))
    tag_item:set_text(string.format("Tag: %s (0x%02x)", name, tag))

    local crc = tvb(len - 1, 1):uint()
    local computed = crc8(tvb, len - 1)
    local crc_item = root:add(f.crc, tvb(len - 1, 1))
    local crc_good = crc == computed
    crc_item:add(f.crc_status, tvb(len - 1, 1), crc_good and 1 or 0):set_generated()
    if not crc_good then
        crc_item:append_text(string.format(" [incorrect, should be 0x%02x]", computed))
        crc_item:add(f.crc_computed, tvb(len - 1, 1), computed):set_generated()
        crc_item:add_proto_expert_info(e.bad_crc,
            string.format("Bad CRC: frame says 0x%02x, content gives 0x%02x", crc, computed))
    end

    root:append_text(string.format(", %s, seq %d", name, seq))
    local summary
    verdict = crc_good and 0 or 1
    if crc_good and tag == 0x50 then
        -- The inner frame's dissection fills in the verdict and Info; the envelope's own
        -- fields and MAC wrap them.
        local summary_auth = dissect_auth(tvb, pinfo, root, to_controller, len)
        last_info = string.format("%s AUTH seq=%d %s", to_controller and "->" or "<-", seq,
            summary_auth or "[bad length]")
        pinfo.cols.info = last_info
        return len
    elseif crc_good then
        local dissectors = to_controller and host_dissectors or controller_dissectors
        local other = to_controller and controller_dissectors or host_dissectors
        local dissect = dissectors[tag]
        if data then root:add(f.data, data):set_hidden() end
        if dissect then
            summary = dissect(root, data, data_len)
        elseif other[tag] then
            root:add_proto_expert_info(e.wrong_direction, string.format("%s only travels %s", name,
                to_controller and "from the controller" or "from a host"))
            summary = "wrong direction"
            refuse(10)
        else
            root:add_proto_expert_info(e.unknown_tag, string.format("Unknown tag 0x%02x", tag))
            summary = "unknown tag"
            refuse(2)
        end
        analyse(pinfo, to_controller, seq, tag, crc, data, data_len)
    else
        summary = "BAD CRC"
    end

    if to_controller then root:add(f.verdict, verdict):set_generated() end
    show_analysis(root, pinfo, to_controller)
    local info = string.format("%s %s seq=%d", to_controller and "->" or "<-", name, seq)
    if summary == nil then
        info = info .. " [bad length]"
    elseif summary ~= "" then
        info = info .. " " .. summary
    end
    local a = analysis[pinfo.number]
    if a and a.retransmission_of then info = info .. " [retransmission]" end
    pinfo.cols.info = info
    last_info = info
    return len
end

local udp_port = DissectorTable.get("udp.port")
local registered_port = DEFAULT_PORT
udp_port:add(registered_port, armctl)

function armctl.prefs_changed()
    if armctl.prefs.port ~= registered_port then
        udp_port:remove(registered_port, armctl)
        registered_port = armctl.prefs.port
        udp_port:add(registered_port, armctl)
    end
end
