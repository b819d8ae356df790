//! The virtual CAN bus's wire: takes the frames every station hands over
//! on `hydractl/can/<interface>/tx`, lets the lowest ID win when the bus
//! frees, holds each for its bits at the configured bitrate, and delivers
//! it to every station on `hydractl/can/<interface>/rx` when its last bit
//! has crossed. The config's `[can]` table names the bus and its bitrate,
//! and `[can.faults]` what the wire does wrong and when (a COB-ID's frames
//! delayed, transmissions destroyed by error frames, the bus off), to try
//! the stack.

use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use hydractl_bus::{clock, run_until, Inlet, Outlet};
use hydractl_can::wire::Wire;
use hydractl_canio::{frame_sample, sample_frame};
use hydractl_samples::{service, CanFrameSample, WireStatus};

/// Frames the wire may be handed between two of its wake-ups.
const TX_BUFFER: usize = 256;
/// How often the wire's counters are published.
const STATUS_EVERY_NS: u64 = 100_000_000;
/// A delivery this late is published at once, not only in the next
/// status: each is the evidence of a deadline miss (`hydractl run`).
const LATE_PUBLISHED_NS: u64 = 100_000;

/// How far the wire's deliveries fell behind their time, ns.
#[derive(Default)]
struct Lateness {
    /// The delivery furthest behind since the last status: (late by, due at).
    since_status: (u64, u64),
    wakeups: u64,
    worst_ns: u64,
}

impl Lateness {
    fn on_delivery(&mut self, late_ns: u64, due_ns: u64) {
        if late_ns > self.since_status.0 {
            self.since_status = (late_ns, due_ns);
        }
        self.worst_ns = self.worst_ns.max(late_ns);
    }
}

fn status(wire: &Wire, seq: u64, late: &Lateness) -> WireStatus {
    let c = wire.counters();
    WireStatus {
        seq,
        stage_time_ns: clock::now_ns(),
        delivered: c.delivered,
        lost: c.lost,
        silenced: c.silenced,
        error_frames: c.error_frames,
        busy_ns: c.busy_ns,
        late_max_ns: late.since_status.0,
        late_max_due_ns: late.since_status.1,
        late_wakeups: late.wakeups,
        late_worst_ns: late.worst_ns,
    }
}

pub fn run() -> Result<()> {
    let started = crate::start("canbus")?;
    let can = started.config.can.clone().unwrap_or_default();
    let tx: Inlet<CanFrameSample> =
        Inlet::open(&started.bus, &service::can_tx(&can.interface), TX_BUFFER).context("the bus's transmit side")?;
    let rx: Outlet<CanFrameSample> =
        Outlet::open(&started.bus, &service::can_rx(&can.interface)).context("the bus's receive side")?;
    let counters: Outlet<WireStatus> =
        Outlet::open(&started.bus, &service::can_wire(&can.interface)).context("the bus's counters")?;
    let mut status_seq = 0u64;
    let mut status_due_ns = clock::now_ns();
    let mut wire = Wire::new(can.bitrate);
    let faults = can.faults.clone();
    let mut faults_on = false;
    // The service keeps each station's last frame for late joiners: one
    // from before this wire started was sent to a wire that is gone.
    let started_ns = clock::now_ns();
    let mut delivered = 0u64;
    let mut late = Lateness::default();
    let mut failure = None;
    started.enter_realtime();
    let inputs = [tx.input()];
    let next_event = |wire: &Wire| {
        wire.next_event_ns().map(|at| {
            let now = clock::now_ns();
            Instant::now() + Duration::from_nanos(at.saturating_sub(now))
        })
    };
    let wire_cell = std::cell::RefCell::new(&mut wire);
    run_until(
        &inputs,
        &started.bus,
        || next_event(&wire_cell.borrow()),
        |_| {
            hydractl_bus::guarded(&mut failure, || -> Result<()> {
                let mut wire = wire_cell.borrow_mut();
                if let Some(f) = &faults {
                    let now = clock::now_ns();
                    let since_s = now.saturating_sub(started_ns) as f64 * 1e-9;
                    let due = since_s >= f.after_s && f.until_s.is_none_or(|u| since_s < u);
                    // What every station's controller reports of the bus.
                    let mut report = None;
                    if due && !faults_on {
                        wire.delay(f.delay_cob_id.map(|id| (id, u64::from(f.delay_us) * 1000)));
                        wire.corrupt(f.error_frames);
                        report = f.bus_off.then(|| wire.go_bus_off());
                    } else if !due && faults_on {
                        wire.delay(None);
                        report = f.bus_off.then(|| wire.restart());
                    }
                    if let Some(frame) = report {
                        delivered += 1;
                        rx.publish(frame_sample(&frame, delivered, now, u32::MAX))?;
                    }
                    faults_on = due;
                }
                while let Some(sample) = tx.next()? {
                    if sample.time_ns >= started_ns {
                        wire.submit(sample_frame(&sample), sample.station, sample.time_ns);
                    }
                }
                loop {
                    let now = clock::now_ns();
                    let Some(delivery) = wire.poll(now) else { break };
                    delivered += 1;
                    late.on_delivery(now.saturating_sub(delivery.end_ns), delivery.end_ns);
                    let mut sample = frame_sample(&delivery.frame, delivered, delivery.end_ns, delivery.station);
                    sample.submitted_ns = delivery.submitted_ns;
                    rx.publish(sample)?;
                }
                let now = clock::now_ns();
                let late_now = late.since_status.0 >= LATE_PUBLISHED_NS;
                if late_now {
                    late.wakeups += 1;
                }
                if now >= status_due_ns || late_now {
                    counters.publish(status(&wire, status_seq, &late))?;
                    late.since_status = (0, 0);
                    status_seq += 1;
                    status_due_ns = now + STATUS_EVERY_NS;
                }
                Ok(())
            })
        },
    )?;
    // The last word, for a run that reads the counters at its end.
    counters.publish(status(&wire_cell.borrow(), status_seq, &late))?;
    failure.map_or(Ok(()), Err)
}
