//! The valve process's desk: where a person and the tools reach the
//! machine's valve. It publishes the device's state and latched fault
//! (`hydractl/valve/device`, for `hydractl status` and the recording) and
//! takes `hydractl valve reset`. Looked at every [`LOOK_EVERY_NS`], not
//! every cycle: neither is part of the loop.

use anyhow::Result;
use hydractl_bus::{clock, Bus, CommandServer, Outlet};
use hydractl_samples::{code, fixed_name, service, SupervisorReply, ValveDevice, ValveRequest};

use super::valve::Actuator;

const LOOK_EVERY_NS: u64 = 20_000_000;
/// The state is published at least this often, changed or not, so that a
/// late reader has it within a look.
const PUBLISH_EVERY_NS: u64 = 100_000_000;
/// A command within this share of the spool's travel is neutral: a reset
/// then moves nothing by itself (ISO 13849-1: a reset shall not start
/// motion).
pub const NEUTRAL_BAND: f64 = 0.02;

pub struct ValveDesk {
    /// `None` for the simulated valve: nothing to publish or reset.
    ports: Option<(Outlet<ValveDevice>, CommandServer<ValveRequest, SupervisorReply>)>,
    last_look_ns: u64,
    last_publish_ns: u64,
    published: ValveDevice,
    reset_time_ns: u64,
}

impl ValveDesk {
    pub fn open(bus: &Bus, can: bool) -> Result<Self> {
        let ports = if can {
            Some((
                Outlet::open(bus, service::VALVE_DEVICE)?,
                CommandServer::open(bus, service::VALVE_COMMAND)?,
            ))
        } else {
            None
        };
        Ok(Self {
            ports,
            last_look_ns: 0,
            last_publish_ns: 0,
            published: ValveDevice::default(),
            reset_time_ns: 0,
        })
    }

    /// Answers a reset request and publishes the device's state, when a
    /// look is due.
    pub fn look(&mut self, actuator: &mut Actuator) -> Result<()> {
        let Some((outlet, commands)) = &self.ports else {
            return Ok(());
        };
        let now = clock::now_ns();
        if now.saturating_sub(self.last_look_ns) < LOOK_EVERY_NS {
            return Ok(());
        }
        self.last_look_ns = now;
        if let Some(request) = commands.receive()? {
            let asked = request.request();
            let answer = if asked.kind == code::VALVE_RESET {
                reset(actuator, asked.serviced != 0)?
            } else {
                Err(format!("no valve request of kind {}", asked.kind))
            };
            if answer.is_ok() {
                self.reset_time_ns = clock::now_ns();
            }
            let (accepted, text) = match answer {
                Ok(text) => (1, text),
                Err(text) => (0, text),
            };
            request.reply(SupervisorReply {
                accepted,
                message: fixed_name(&text),
                ..SupervisorReply::default()
            })?;
        }
        let Some(valve) = actuator.can_valve() else {
            return Ok(());
        };
        let mut device = ValveDevice {
            reset_time_ns: self.reset_time_ns,
            resets: valve.resets(),
            state: fixed_name(valve.state_name()),
            ..ValveDevice::default()
        };
        if let Some(fault) = valve.latched() {
            device.latched = 1;
            device.fault_code = fault.code;
            device.latched_since_unix_ns = (fault.since_unix_s * 1e9) as u64;
            device.meaning = fixed_name(&fault.meaning);
        }
        let unchanged = ValveDevice {
            seq: self.published.seq,
            stage_time_ns: self.published.stage_time_ns,
            ..device
        } == self.published;
        if unchanged && now.saturating_sub(self.last_publish_ns) < PUBLISH_EVERY_NS {
            return Ok(());
        }
        device.seq = self.published.seq + u64::from(self.last_publish_ns != 0);
        device.stage_time_ns = now;
        outlet.publish(device)?;
        self.published = device;
        self.last_publish_ns = now;
        Ok(())
    }
}

/// A person's reset: refused unless the command the loop asks of the
/// machine's valve is neutral (the loop on the simulated plant asks
/// nothing of it).
fn reset(actuator: &mut Actuator, serviced: bool) -> Result<std::result::Result<String, String>> {
    let requested = actuator.last_requested;
    let on_machine = actuator.on_machine();
    let Some(valve) = actuator.can_valve() else {
        return Ok(Err("the loop drives the simulated valve: nothing to reset".to_owned()));
    };
    if valve.latched().is_none() {
        return Ok(Err(format!("no fault is latched; the valve is {}", valve.state_name())));
    }
    if on_machine && requested.abs() > NEUTRAL_BAND {
        return Ok(Err(format!(
            "the loop asks {:.1} % of the spool's travel of the machine's valve, not neutral (within {:.0} %): \
             a reset would move the load. Bring the loop to neutral, or run it on the simulated plant \
             (`hydractl plant sim`), then reset",
            requested * 100.0,
            NEUTRAL_BAND * 100.0
        )));
    }
    valve.reset(serviced)
}
