//! The controller's boot state, written once for [`Controller::new`] and
//! [`Controller::init_in_place`].

use core::mem::MaybeUninit;

use protocol::{MAX_JOINTS, MoreFlags, NetSettings, State, limits};

use super::{ALL_DRIVERS, Controller};
use crate::buffer::TrajectoryBuffer;
use crate::config::ControllerConfig;
use crate::hw::PersistentSettings;
use crate::link::{RecentFrames, UploadOrder};
use crate::reports::LOCATION_LISTENERS;

/// The boot value of every [`Controller`] field but the trajectory buffer, written once for
/// [`Controller::new`] (a struct literal: the compiler checks that no field is missing) and
/// [`Controller::init_in_place`] (the same list, each field written where it lies).
/// `$emit!($($head)* ; field: value, ...)` is called with the list.
macro_rules! with_boot_fields {
    ($config:expr, $emit:ident!($($head:tt)*)) => {
        $emit!($($head)* ;
        config: $config,
        settings: PersistentSettings::DEFAULT,
        state: State::Stopped,
        expected: 0,
        received: 0,
        executed: 0,
        received_end: [0; MAX_JOINTS],
        fed_end: [0; MAX_JOINTS],
        return_pending: false,
        gripper_pulse_count: 0,
        return_plan: None,
        return_fault: None,
        order: UploadOrder::new(),
        uploader: None,
        recent: RecentFrames::new(),
        owner: None,
        listeners: [None; LOCATION_LISTENERS],
        location_claimer: None,
        last_handled_us: 0,
        discover_budget: super::ReplyBudget::new(),
        glance_budget: super::ReplyBudget::new(),
        sessions: crate::auth::Sessions::new(),
        entropy: 0,
        keys_set: 0,
        saving: None,
        serial_to: None,
        more_flags: MoreFlags(0),
        hard_limits: crate::switches::Limits::new(),
        reports_on: true,
        upload_period_us: limits::DEFAULT_UPLOAD_PERIOD_US,
        enabled: ALL_DRIVERS,
        pins: [false; 2],
        serial: None,
        stop: protocol::StopReport::COMPLETE,
        last_stopper: None,
        received_last: super::runs::LastSegment::REST,
        mac: [0; 6],
        booted_net: NetSettings::fixed([192, 168, 1, 30], 24, None),
        step_budget_hz: crate::profile::BOOT_STEP_BUDGET_HZ,
        motion: super::motion::Motion::IDLE,
        last_refusal: protocol::Refusal {
            seq: 0,
            tag: 0,
            point: 0,
            joint: 0,
            reason: protocol::RefusalReason::None,
            value: 0,
            limit: 0,
        },
        )
    };
}

/// `Controller { buffer, boot fields }`: see `with_boot_fields`.
macro_rules! controller_literal {
    ($buffer:expr ; $($field:ident : $value:expr),* $(,)?) => {
        Controller { buffer: $buffer, $($field: $value),* }
    };
}

/// Writes each boot field through the pointer `$slot`: see `with_boot_fields`.
macro_rules! write_fields {
    ($slot:expr ; $($field:ident : $value:expr),* $(,)?) => {
        $( (&raw mut (*$slot).$field).write($value); )*
    };
}

impl<const CAP: usize> Controller<CAP> {
    /// A controller in its boot state: STOPPED, drivers enabled, reports on.
    pub const fn new(config: ControllerConfig) -> Self {
        with_boot_fields!(
            config,
            controller_literal!(TrajectoryBuffer::new(config.capacity))
        )
    }

    /// Builds a controller in its boot state in place, in `slot` (a static's storage), and
    /// returns it: the same value as [`Controller::new`], but never built on the stack first.
    /// A board's controller is 300 KB, more than its stack; `StaticCell::init(new())` relies
    /// on the compiler to elide that copy, which it does not at every optimisation level.
    pub fn init_in_place(slot: &mut MaybeUninit<Self>, config: ControllerConfig) -> &mut Self {
        let p = slot.as_mut_ptr();
        // SAFETY: `p` points to `slot`'s storage, valid for writes and aligned; every field
        // is written below (the buffer by its own in-place constructor, the others from the
        // list that `new`'s struct literal proves complete), so the value is initialised.
        unsafe {
            TrajectoryBuffer::init_in_place(&raw mut (*p).buffer, config.capacity);
            with_boot_fields!(config, write_fields!(p));
            slot.assume_init_mut()
        }
    }
}
