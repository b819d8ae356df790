//! The machine's sensors on CAN, as the machine process reads them: it is
//! the SYNC producer and the PDO consumer. Each period it sends SYNC,
//! gathers the encoder's and transducers' TPDOs that answer it until
//! `[can] pdo_deadline_us`, and returns what came: a value that did not
//! come is NaN (the sensor stage marks the reading invalid and the valve's
//! guard holds neutral), never waited for past the deadline, never the
//! last period's. It starts the sensor nodes (NMT) and starts again any
//! that reports itself not operational; a node whose heartbeat stops is a
//! lost machine.

use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use hydractl_bus::can::{open_port, CanPort, Filter};
use hydractl_bus::{clock, wait_input, Bus};
use hydractl_can::canopen::{self, cob_id, NmtCommand, NmtState, NodeId};
use hydractl_can::ecu::set_heartbeat;
use hydractl_can::master::{SensorMaster, SensorValues};
use hydractl_can::profile::Profile;

pub struct CanSensors {
    port: Box<dyn CanPort>,
    master: SensorMaster,
    deadline: Duration,
    heartbeat_ms: u16,
    /// Periods with a PDO missing at the deadline.
    pub late_periods: u64,
    /// PDOs refused (wrong length, a value out of the type's range).
    pub bad_frames: u64,
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
        })
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
