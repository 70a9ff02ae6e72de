//! The emulated board's small devices: PIN0/PIN1 and the ENABLE lines as logged levels, a
//! gripper timer that keeps time instead of toggling a pin, and settings in RAM.

use core::cell::Cell;

use arm_core::hw::{Gripper, Outputs, PersistentSettings, SettingsStore};
use embassy_sync::blocking_mutex::Mutex;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_time::Instant;
use protocol::Pwm;

use crate::mps2::SYSCLK_HZ;

/// PIN0/PIN1 and the ENABLE lines: levels kept and every change logged.
#[derive(Default)]
pub struct LoggedOutputs {
    user_pins: u8,
    enabled: u16,
}

impl Outputs for LoggedOutputs {
    fn set_user_pin(&mut self, pin: u8, high: bool) {
        let bit = 1u8 << (pin & 1);
        let before = self.user_pins;
        if high {
            self.user_pins |= bit;
        } else {
            self.user_pins &= !bit;
        }
        if before != self.user_pins {
            log::info!("PIN{} {}", pin & 1, if high { "high" } else { "low" });
        }
    }

    fn set_enabled(&mut self, enabled: u16) {
        if enabled != self.enabled {
            log::info!("ENABLE lines {:#05x}", enabled);
        }
        self.enabled = enabled;
    }
}

/// The gripper timer's input clock: SYSCLK, as a CMSDK timer would count it (the
/// profile's `pwm_timer_clock_hz`).
pub const GRIPPER_CLOCK_HZ: u32 = crate::step_out::PROFILE.pwm_timer_clock_hz;
const _: () = assert!(GRIPPER_CLOCK_HZ == SYSCLK_HZ);

/// A gripper timer without an output pin: servo PWM runs until stopped; a counted burst
/// ends by itself after its pulses' time, as the NUCLEO's one-pulse timer does.
#[derive(Default)]
pub struct TimedGripper {
    running: bool,
    /// End of the counted burst, if one is running.
    burst_end: Option<Instant>,
}

impl Gripper for TimedGripper {
    fn timer_clock_hz(&self) -> u32 {
        GRIPPER_CLOCK_HZ
    }

    fn start(&mut self, pwm: &Pwm) {
        self.running = true;
        self.burst_end = (pwm.pulse_count != 0).then(|| {
            let ticks = pwm.period_ticks() * u64::from(pwm.pulse_count.unsigned_abs());
            let us = ticks * 1_000_000 / u64::from(GRIPPER_CLOCK_HZ);
            Instant::now() + embassy_time::Duration::from_micros(us)
        });
        log::info!(
            "gripper on: psc {} arr {} ccr1 {} pulses {}",
            pwm.psc,
            pwm.arr,
            pwm.ccr1,
            pwm.pulse_count
        );
    }

    fn stop(&mut self) {
        if self.running {
            log::info!("gripper off");
        }
        self.running = false;
        self.burst_end = None;
    }

    fn is_active(&self) -> bool {
        self.running && self.burst_end.is_none_or(|end| Instant::now() < end)
    }
}

/// The address QEMU's user-mode network gives its first guest (`-nic user`), which its
/// `hostfwd` forwards to.
pub const QEMU_GUEST_IP: [u8; 4] = [10, 0, 2, 15];

/// Settings in RAM: they survive a reconnect, not a restart of QEMU.
static STORED: Mutex<CriticalSectionRawMutex, Cell<Option<PersistentSettings>>> =
    Mutex::new(Cell::new(None));

/// [`SettingsStore`] in RAM, starting at `boot` (the defaults with QEMU's guest address).
pub struct RamSettings;

impl RamSettings {
    /// The store, holding `boot` until something is saved.
    pub fn new(boot: PersistentSettings) -> Self {
        STORED.lock(|s| s.set(Some(boot)));
        RamSettings
    }

    /// What is stored now.
    pub fn current(&self) -> Option<PersistentSettings> {
        STORED.lock(|s| s.get())
    }
}

/// Settings in RAM cannot fail.
#[derive(Clone, Copy, Debug)]
pub enum Never {}

impl SettingsStore for RamSettings {
    type Error = Never;

    async fn load(&mut self) -> Result<Option<PersistentSettings>, Never> {
        Ok(self.current())
    }

    async fn save(&mut self, settings: &PersistentSettings) -> Result<(), Never> {
        log::info!(
            "settings saved (RAM): joints {} ip {:?}/{}",
            settings.joints,
            settings.ip,
            settings.prefix_len
        );
        STORED.lock(|s| s.set(Some(*settings)));
        Ok(())
    }
}
