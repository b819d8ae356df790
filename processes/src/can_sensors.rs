//! The machine's sensors on CAN, as the machine process reads them: it is
//! the SYNC producer and the PDO consumer. Each period it sends SYNC,
//! gathers the encoder's and transducers' TPDOs that answer it until
//! `[can] pdo_deadline_us`, and returns what came: a value that did not
//! come is NaN (the sensor stage marks the reading invalid and the valve's
//! guard holds neutral), never waited for past the deadline, never the
//! last period's. It starts the sensor nodes (NMT) and starts again any
//! that reports itself not operational; a node whose heartbeat stops is a
//! lost machine. It hears the valve's status and EMCY too: when the valve
//! holds its spool at neutral is the valve's to say (its own timeout), not
//! the simulated amplifier's figure.

use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use hydractl_bus::{clock, wait_input, Bus};
use hydractl_can::canopen::{self, cob_id, NmtCommand, NmtState, NodeId};
use hydractl_can::heartbeat::set_heartbeat;
use hydractl_can::master::{SensorMaster, SensorValues};
use hydractl_can::profile::{Pdo, Profile};
use hydractl_can::valve::DeviceState;
use hydractl_canio::{open_port, CanPort, Filter};

pub struct CanSensors {
    port: Box<dyn CanPort>,
    master: SensorMaster,
    deadline: Duration,
    heartbeat_ms: u16,
    /// Periods with a PDO missing at the deadline.
    pub late_periods: u64,
    /// PDOs refused (wrong length, a value out of the type's range).
    pub bad_frames: u64,
    valve_status: Pdo,
    valve_status_word_at: (usize, u8),
    valve_emcy: u16,
    /// The valve was Active by its last word; since when it is not, after
    /// it was (its status, or an EMCY), ns.
    valve_active: bool,
    valve_held_since_ns: Option<u64>,
}

impl CanSensors {
    pub fn open(bus: &Bus, profile: &Profile) -> Result<Self> {
        let master = SensorMaster::new(profile);
        let mut filters = vec![Filter::exact(profile.encoder_position.cob_id)];
        for channel in &profile.pressure {
            filters.push(Filter::exact(channel.value.cob_id));
        }
        for node in master.nodes() {
            filters.push(Filter::exact(cob_id::heartbeat(node)));
        }
        filters.push(Filter::exact(profile.valve_status.cob_id));
        filters.push(Filter::exact(cob_id::emcy(profile.valve)));
        let port = open_port(bus, profile, &filters).context("the sensors' CAN bus")?;
        for start in master.start_frames() {
            port.send(&start)
                .context("starting the sensor nodes (heartbeat by SDO, NMT)")?;
        }
        Ok(Self {
            port,
            master,
            deadline: Duration::from_micros(u64::from(profile.pdo_deadline_us)),
            heartbeat_ms: profile.heartbeat_ms,
            late_periods: 0,
            bad_frames: 0,
            valve_status: profile.valve_status,
            valve_status_word_at: profile.valve_status_word_at,
            valve_emcy: cob_id::emcy(profile.valve),
            valve_active: false,
            valve_held_since_ns: None,
        })
    }

    /// The valve's own word on its spool: a status that is not Active, or
    /// an EMCY, after it was Active, holds it at neutral from then on.
    fn hear_valve(&mut self, frame: &hydractl_can::Frame, time_ns: u64) -> bool {
        let id = frame.id as u16;
        let active = if id == self.valve_status.cob_id {
            let Ok(values) = self.valve_status.mapping.unpack(frame, "valve status TPDO") else {
                return true;
            };
            let word = values[self.valve_status.slot(self.valve_status_word_at)] as u16;
            DeviceState::from_status_word(word, true) == DeviceState::Active
        } else if id == self.valve_emcy && frame.data[..2] != [0, 0] {
            false
        } else {
            return false;
        };
        if active {
            self.valve_held_since_ns = None;
        } else if self.valve_active || self.valve_held_since_ns.is_some() {
            self.valve_held_since_ns.get_or_insert(time_ns);
        }
        self.valve_active = active;
        true
    }

    /// How long the valve has held its spool at neutral by its own word,
    /// ns; `None` while it follows its set point (or before it ever did).
    pub fn valve_held_for_ns(&self) -> Option<u64> {
        self.valve_held_since_ns.map(|t| clock::now_ns().saturating_sub(t))
    }

    /// One period: SYNC, then its PDOs until they are all in or the
    /// deadline passes. Returns the values and the SYNC's time, when the
    /// sensors sampled.
    pub fn acquire(&mut self) -> Result<(SensorValues, u64)> {
        // What came since the last period: heartbeats, and PDOs too late
        // for it (they count for nothing now).
        self.drain(u64::MAX)?;
        let sync = self.master.sync();
        let sync_time_ns = clock::now_ns();
        self.port.send(&sync).context("sending SYNC")?;
        let deadline = Instant::now() + self.deadline;
        loop {
            self.drain(sync_time_ns)?;
            if self.master.complete() {
                break;
            }
            let remaining = deadline.saturating_duration_since(Instant::now());
            if remaining.is_zero() {
                self.late_periods += 1;
                break;
            }
            wait_input(self.port.input(), remaining)?;
        }
        Ok((self.master.values(), sync_time_ns))
    }

    /// Takes what waits: heartbeats always, values only from frames that
    /// crossed the bus after `values_since_ns` (this period's SYNC).
    fn drain(&mut self, values_since_ns: u64) -> Result<()> {
        while let Some(received) = self.port.receive()? {
            if self.hear_valve(&received.frame, received.time_ns) {
                continue;
            }
            let heartbeat = canopen::decode_heartbeat(&received.frame).ok();
            if heartbeat.is_none() && received.time_ns < values_since_ns {
                continue;
            }
            match self.master.on_frame(&received.frame, received.time_ns) {
                Ok(_) => {}
                // Counted; the value stays missing.
                Err(_) => self.bad_frames += 1,
            }
            // A node that rebooted, was stopped or missed its start gets its
            // heartbeat time and its start again.
            if let Some((node, state)) = heartbeat {
                if state != NmtState::Operational && self.master.nodes().contains(&node) {
                    self.port
                        .send(&set_heartbeat(node, self.heartbeat_ms))
                        .context("setting a sensor node's heartbeat (SDO)")?;
                    self.port
                        .send(&canopen::nmt(NmtCommand::Start, node))
                        .context("restarting a sensor node (NMT)")?;
                }
            }
        }
        Ok(())
    }

    /// A sensor node heard and then silent for the heartbeat timeout.
    pub fn lost(&self) -> Option<NodeId> {
        self.master.lost(clock::now_ns())
    }
}
