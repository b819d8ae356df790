//! The machine's valve on CAN, as the valve process drives it (CiA 408
//! through hydractl-can's `ValveMaster`). At start it starts the node
//! (NMT) and steps the control word to Active, a fault left by an earlier
//! process (its RPDO timeout) cleared by R low then high; until the valve
//! reports Active every set point it sends is neutral. Every command goes
//! out in the set point RPDO: the valve's own RPDO timeout is the guard of
//! last resort when this process dies.
//!
//! A valve that faults once Active (an EMCY, a fault state) or whose
//! heartbeat stops is latched: from then on only neutral is sent, the
//! fault is published, and the process ends so that the supervisor starts
//! it again, which brings the valve up afresh.

use anyhow::{Context, Result};
use hydractl_bus::can::{open_port, CanPort, Filter};
use hydractl_bus::{clock, Bus};
use hydractl_can::canopen::{cob_id, Emergency, NmtState};
use hydractl_can::master::{ValveFrame, ValveMaster};
use hydractl_can::profile::Profile;
use hydractl_can::valve::DeviceState;

/// Why the valve was given up on.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ValveFault {
    Emergency(Emergency),
    State(DeviceState),
    HeartbeatLost,
    NotOperational(NmtState),
}

impl std::fmt::Display for ValveFault {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Emergency(e) => write!(f, "EMCY {:#06x} ({})", e.code, e.describe()),
            Self::State(s) => write!(f, "the valve reports {}", s.name()),
            Self::HeartbeatLost => write!(f, "the valve's heartbeat stopped"),
            Self::NotOperational(state) => write!(f, "the valve's heartbeat says {}", state.name()),
        }
    }
}

pub struct CanValve {
    port: Box<dyn CanPort>,
    master: ValveMaster,
    /// Reached Active in this process: from then on a fault is latched.
    was_active: bool,
    fault: Option<ValveFault>,
    pub bad_frames: u64,
}

impl CanValve {
    pub fn open(bus: &Bus, profile: &Profile) -> Result<Self> {
        let master = ValveMaster::new(profile);
        let node = master.node();
        let filters = [
            Filter::exact(profile.valve_status.cob_id),
            Filter::exact(cob_id::emcy(node)),
            Filter::exact(cob_id::heartbeat(node)),
        ];
        let port = open_port(bus, profile, &filters).context("the valve's CAN bus")?;
        for frame in master.start_frames() {
            port.send(&frame)
                .context("starting the valve node (heartbeat by SDO, NMT)")?;
        }
        Ok(Self {
            port,
            master,
            was_active: false,
            fault: None,
            bad_frames: 0,
        })
    }

    /// Takes what the valve said since the last call.
    fn listen(&mut self) -> Result<()> {
        while let Some(received) = self.port.receive()? {
            let Ok(what) = self.master.on_frame(&received.frame, received.time_ns) else {
                self.bad_frames += 1;
                continue;
            };
            match what {
                ValveFrame::Heartbeat(state) if state != NmtState::Operational => {
                    if self.was_active {
                        // Rebooted or stopped under us: its state is gone.
                        self.fault.get_or_insert(ValveFault::NotOperational(state));
                    } else {
                        // Missed its start (or booted after it): again.
                        for frame in self.master.start_frames() {
                            self.port.send(&frame).context("starting the valve node again")?;
                        }
                    }
                }
                ValveFrame::Status(DeviceState::Active) => self.was_active = true,
                ValveFrame::Status(state) if self.was_active && state.is_fault() => {
                    self.fault.get_or_insert(ValveFault::State(state));
                }
                ValveFrame::Emergency(e) if self.was_active && e.code != 0 => {
                    self.fault.get_or_insert(ValveFault::Emergency(e));
                }
                _ => {}
            }
        }
        if self.was_active && self.master.lost(clock::now_ns()) {
            self.fault.get_or_insert(ValveFault::HeartbeatLost);
        }
        Ok(())
    }

    /// Sends `command` (neutral unless the valve is Active and `drive` is
    /// set, and always once a fault is latched), with the next bring-up
    /// step while the valve is not yet Active.
    pub fn drive(&mut self, command: f64, drive: bool) -> Result<()> {
        self.listen()?;
        let command = if drive && self.fault.is_none() { command } else { 0.0 };
        let set_point = self.master.set_point_frame(command)?;
        self.port.send(&set_point).context("sending the valve's set point")?;
        // Brought up for the machine's readings only: not by the neutral of
        // a start or an end, not for the simulated plant.
        if self.fault.is_none() && drive {
            if let Some(control) = self.master.bring_up_frame()? {
                self.port.send(&control).context("bringing the valve up")?;
            }
        }
        Ok(())
    }

    /// Neutral, and the valve to hold: the process is leaving.
    pub fn hold(&mut self) -> Result<()> {
        let set_point = self.master.set_point_frame(0.0)?;
        self.port.send(&set_point).context("sending neutral")?;
        let hold = self.master.hold_frame()?;
        self.port.send(&hold).context("holding the valve")?;
        Ok(())
    }

    pub fn fault(&self) -> Option<ValveFault> {
        self.fault
    }

    pub fn active(&self) -> bool {
        self.master.active()
    }

    pub fn emcys(&self) -> u64 {
        self.master.emcys()
    }
}
