//! The machine's valve on CAN, as the valve process drives it (CiA 408
//! through hydractl-can's `ValveMaster`). At start it starts the node
//! (NMT), writes the valve's own guard (the set point RPDO's timeout) and
//! heartbeat by SDO and reads them back, then steps the control word to
//! Active; until the valve reports Active every set point it sends is
//! neutral. Every command goes out in the set point RPDO: the valve's own
//! timeout is the guard of last resort when this process dies.
//!
//! Every fault is latched, whenever it is seen (bring-up included): an
//! EMCY, a fault state, a heartbeat that stops or says the node left
//! operational, a setting the valve refuses. Latched, it is written to the
//! [`FaultLatch`] before anything else, only neutral is sent, the valve is
//! told to hold, and nothing clears it but [`CanValve::reset`], a person's
//! command: not a restart of this process, nor of the stack.
//! [`fault_code`] numbers the faults that are not the valve's own EMCYs.

use anyhow::{Context, Result};
use hydractl_bus::{clock, Bus};
use hydractl_can::canopen::{cob_id, Emergency, NmtState};
use hydractl_can::master::{ValveFrame, ValveMaster};
use hydractl_can::profile::Profile;
use hydractl_can::spool::SpoolWatch;
use hydractl_can::valve::{fault_code, fault_code_name, DeviceState};
use hydractl_canio::{open_port, CanPort, Filter};

use crate::valve_latch::{FaultLatch, LatchedFault};

/// After a reset, a fault status sent before the valve took the reset may
/// still come; past this, a fault status is the reset not taking.
const RESET_SETTLE_NS: u64 = 50_000_000;
/// While the master drives the valve, a status answers every SYNC: none
/// for this long is a valve that stopped answering (this computer's own
/// stalls reach 33 ms).
pub(crate) const STATUS_TIMEOUT_NS: u64 = 100_000_000;
/// Nothing at all from the valve this long after the master started: no
/// valve on the bus (a node ID that is not the valve's, a cut cable).
pub(crate) const NEVER_HEARD_NS: u64 = 2_000_000_000;
/// A frame the bus refuses (a full transmit queue) is tried again at once,
/// this many times in all; only a run of [`FAILED_WRITES_FAULT`] frames
/// that could not be sent is a fault.
const WRITE_ATTEMPTS: u32 = 3;
pub(crate) const FAILED_WRITES_FAULT: u32 = 5;

/// What a reset did, in words, or why it was refused.
pub type ResetAnswer = std::result::Result<String, String>;

pub struct CanValve {
    port: Box<dyn CanPort>,
    master: ValveMaster,
    latch: FaultLatch,
    /// Reached Active in this process: a heartbeat's NMT state other than
    /// operational is then the valve rebooted or stopped under the loop.
    was_active: bool,
    /// A reset's frames went out at this time: fault statuses are taken as
    /// the old fault's until the valve reports a state without one, or
    /// [`RESET_SETTLE_NS`] passed.
    reset_at_ns: Option<u64>,
    resets: u32,
    opened_ns: u64,
    /// Anything from the valve (heartbeat, status, EMCY, SDO) since start.
    heard: bool,
    /// The set point the valve was last sent while Active and driven.
    following: Option<f64>,
    spool: SpoolWatch,
    writes: WriteRun,
    pub bad_frames: u64,
}

impl CanValve {
    pub fn open(bus: &Bus, profile: &Profile, latch: FaultLatch) -> Result<Self> {
        let master = ValveMaster::new(profile);
        let node = master.node();
        let filters = [
            Filter::exact(profile.valve_status.cob_id),
            Filter::exact(cob_id::emcy(node)),
            Filter::exact(cob_id::heartbeat(node)),
            Filter::exact(cob_id::sdo_response(node)),
        ];
        let port = open_port(bus, profile, &filters).context("the valve's CAN bus")?;
        port.send(&master.start_frame())
            .context("starting the valve node (NMT)")?;
        Ok(Self {
            port,
            master,
            latch,
            was_active: false,
            reset_at_ns: None,
            resets: 0,
            opened_ns: clock::now_ns(),
            heard: false,
            following: None,
            spool: SpoolWatch::new(profile.valve_spool_tolerance, profile.valve_spool_hold_ms),
            writes: WriteRun::default(),
            bad_frames: 0,
        })
    }

    /// Latches a fault: written down first, then acted on (neutral, hold).
    fn latch(&mut self, code: u32, meaning: String) -> Result<()> {
        self.latch.latch(code, meaning)
    }

    fn settling(&self, now_ns: u64) -> bool {
        self.reset_at_ns
            .is_some_and(|t| now_ns.saturating_sub(t) < RESET_SETTLE_NS)
    }

    /// Takes what the valve said since the last call.
    fn listen(&mut self) -> Result<()> {
        while let Some(received) = self.port.receive()? {
            if let Some((code, meaning)) = received.frame.bus_fault() {
                self.latch(u32::from(code), meaning.to_owned())?;
                continue;
            }
            let Ok(what) = self.master.on_frame(&received.frame, received.time_ns) else {
                self.bad_frames += 1;
                continue;
            };
            self.heard |= what != ValveFrame::Other;
            if let ValveFrame::Status(_) = what {
                if let Some(fault) = self
                    .spool
                    .on_status(self.following, self.master.actual(), received.time_ns)
                {
                    self.latch(fault_code::SPOOL, fault.to_string())?;
                }
            }
            match what {
                ValveFrame::Heartbeat(state) if state != NmtState::Operational => {
                    if self.was_active {
                        self.latch(
                            fault_code::HEARTBEAT,
                            format!("the valve's heartbeat says {}: it rebooted or stopped", state.name()),
                        )?;
                    } else if state == NmtState::BootUp || state == NmtState::PreOperational {
                        // Missed its start (or booted after it): again,
                        // its settings included.
                        self.master.restart();
                        self.port
                            .send(&self.master.start_frame())
                            .context("starting the valve node again")?;
                    }
                }
                ValveFrame::Status(DeviceState::Active) => {
                    self.was_active = true;
                    self.reset_at_ns = None;
                }
                ValveFrame::Status(state) if state.is_fault() && !self.settling(received.time_ns) => {
                    let when = if self.was_active {
                        ""
                    } else {
                        " at bring-up (faulted before)"
                    };
                    self.latch(
                        fault_code::STATE | u32::from(state.status_word()),
                        format!("the valve reports {}{when}", state.name()),
                    )?;
                }
                ValveFrame::Status(state) if state.is_fault() => {}
                ValveFrame::Status(_) => self.reset_at_ns = None,
                ValveFrame::Emergency(e) if e.code != 0 => {
                    self.latch(u32::from(e.code), emergency_meaning(&e))?;
                }
                _ => {}
            }
        }
        let now = clock::now_ns();
        if self.was_active && self.master.lost(now) {
            self.latch(fault_code::HEARTBEAT, "the valve's heartbeat stopped".to_owned())?;
        }
        if !self.heard && now.saturating_sub(self.opened_ns) > NEVER_HEARD_NS {
            self.latch(
                fault_code::NEVER_HEARD,
                format!(
                    "nothing heard from the valve (node {:#04x}) in {} s since start",
                    self.master.node(),
                    NEVER_HEARD_NS / 1_000_000_000
                ),
            )?;
        }
        if let (Some(_), Some(status_ns)) = (self.following, self.master.status_time_ns()) {
            let silent_ns = now.saturating_sub(status_ns);
            if silent_ns > STATUS_TIMEOUT_NS {
                self.latch(
                    fault_code::STATUS_MISSING,
                    format!(
                        "no status from the valve for {} ms while it was driven",
                        silent_ns / 1_000_000
                    ),
                )?;
            }
        }
        if let Some(e) = self.master.settings_failed() {
            let meaning = e.to_string();
            self.latch(fault_code::SETTING, meaning)?;
        }
        Ok(())
    }

    /// Sends `command` (neutral unless the valve is Active, `drive` is
    /// set and no fault is latched), with the next bring-up step while the
    /// valve is not yet Active. Returns whether the valve applies it.
    pub fn drive(&mut self, command: f64, drive: bool) -> Result<bool> {
        self.listen()?;
        let latched = self.latch.latched().is_some();
        let applied = drive && !latched && self.master.active();
        self.following = applied.then(|| hydractl_can::valve::spool_position(hydractl_can::valve::set_point(command)));
        let set_point = self.master.set_point_frame(if applied { command } else { 0.0 })?;
        self.send(&set_point, "the set point")?;
        if let Some(request) = self.master.setting_frame(clock::now_ns()) {
            self.send(&request, "a setting by SDO")?;
        }
        if latched {
            // A valve still Active under a fault only the master saw.
            if self.master.active() {
                let hold = self.master.hold_frame()?;
                self.send(&hold, "hold")?;
            }
        } else if drive {
            // Brought up for the machine's readings only: not by the
            // neutral of a start or an end, not for the simulated plant.
            if let Some(control) = self.master.bring_up_frame()? {
                self.send(&control, "the bring-up's control word")?;
            }
        }
        Ok(applied)
    }

    /// Sends `frame`, tried again at once when the bus refuses it; a run
    /// of frames that could not be sent is a latched fault, one alone is
    /// not (the next period sends again).
    fn send(&mut self, frame: &hydractl_can::Frame, what: &str) -> Result<()> {
        let port = &self.port;
        if let Some((run, why)) = self.writes.send(|| port.send(frame)) {
            self.latch(
                fault_code::WRITES_REFUSED,
                format!("{run} frames in a row not sent ({what}): {why}"),
            )?;
        }
        Ok(())
    }

    /// A person's reset of the latched fault. Refused when nothing is
    /// latched, or the valve needs service; `at_neutral` is the caller's
    /// judgement of the command (the valve is driven from neutral after).
    pub fn reset(&mut self, serviced: bool) -> Result<ResetAnswer> {
        let now = clock::unix_now_s();
        let fault = match self.latch.may_reset(serviced, now) {
            Ok(fault) => fault,
            Err(refusal) => return Ok(Err(refusal.to_string())),
        };
        // Written down before the edge goes out: a crash between the two
        // leaves the valve faulted (safe), never reset and still latched.
        self.latch.reset(serviced, now)?;
        for frame in self.master.reset_frames()? {
            self.port.send(&frame).context("sending the fault reset")?;
        }
        self.master.restart();
        self.reset_at_ns = Some(clock::now_ns());
        self.was_active = false;
        self.resets += 1;
        Ok(Ok(format!(
            "reset {} ({}), latched {:.1} s ago; the valve is brought up again from neutral",
            fault_code_name(fault.code),
            fault.meaning,
            (now - fault.since_unix_s).max(0.0)
        )))
    }

    /// Neutral, and the valve to hold: the process is leaving.
    pub fn hold(&mut self) -> Result<()> {
        let set_point = self.master.set_point_frame(0.0)?;
        self.port.send(&set_point).context("sending neutral")?;
        let hold = self.master.hold_frame()?;
        self.port.send(&hold).context("holding the valve")?;
        Ok(())
    }

    pub fn latched(&self) -> Option<&LatchedFault> {
        self.latch.latched()
    }

    /// The device's state in words.
    pub fn state_name(&self) -> &'static str {
        self.master.state().map_or("not heard", DeviceState::name)
    }

    pub fn resets(&self) -> u32 {
        self.resets
    }
}

fn emergency_meaning(e: &Emergency) -> String {
    format!("EMCY {:#06x}: {}", e.code, e.describe())
}

/// Frames in a row that could not be sent, each after its retries.
#[derive(Debug, Default)]
struct WriteRun {
    failed: u32,
}

impl WriteRun {
    /// Tries `send` up to [`WRITE_ATTEMPTS`] times. `Some` (the run's
    /// length and the last error) once [`FAILED_WRITES_FAULT`] frames in a
    /// row could not be sent.
    fn send<E: std::fmt::Display>(
        &mut self,
        mut send: impl FnMut() -> std::result::Result<(), E>,
    ) -> Option<(u32, String)> {
        let mut last_error = String::new();
        for _ in 0..WRITE_ATTEMPTS {
            match send() {
                Ok(()) => {
                    self.failed = 0;
                    return None;
                }
                Err(e) => last_error = e.to_string(),
            }
        }
        self.failed += 1;
        (self.failed >= FAILED_WRITES_FAULT).then_some((self.failed, last_error))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_refused_write_is_tried_again_and_only_a_run_of_them_is_a_fault() {
        let mut writes = WriteRun::default();
        // Refused twice, then taken: no fault, and the run starts again.
        let mut calls = 0;
        let refused_twice = writes.send(|| {
            calls += 1;
            if calls < 3 {
                Err("no buffer space")
            } else {
                Ok(())
            }
        });
        assert_eq!((refused_twice, calls), (None, 3));
        for frame in 1..FAILED_WRITES_FAULT {
            assert_eq!(writes.send(|| Err("no buffer space")), None, "frame {frame}");
        }
        let fault = writes.send(|| Err("no buffer space")).expect("a run of them");
        assert_eq!(fault, (FAILED_WRITES_FAULT, "no buffer space".to_owned()));
        assert_eq!(writes.send(|| Ok::<(), &str>(())), None);
        assert_eq!(writes.failed, 0);
    }
}
