//! The virtual CAN bus's wire, as plain state and no clock of its own:
//! frames wait until the bus is free, the lowest arbitration field wins
//! (standard before extended of the same base ID, data before remote),
//! and each holds the bus for its own bits at the bitrate, stuffing
//! included. For tests it silences a station, delays frames and corrupts
//! a transmission with an error frame, after which the sender retries as
//! a CAN controller does. Fixed capacity: nothing allocates per frame.

use crate::timing::{bus_time_ns, frame_bits};
use crate::Frame;

/// Frames waiting for the bus at most; a full queue loses the frame and
/// counts it, as a controller's full transmit buffer does.
pub(crate) const PENDING: usize = 64;
/// Stations that may be silenced at once.
const SILENCED: usize = 8;
/// An error flag (6), its superposition (up to 6) and delimiter (8), and
/// the intermission (3).
const ERROR_FRAME_BITS: u32 = 23;
use crate::frame::error_class::PROTOCOL as ERROR_CLASS_PROTOCOL;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Pending {
    pub frame: Frame,
    /// Who sent it (a process on the virtual bus).
    pub station: u32,
    pub submitted_ns: u64,
    /// When it may first contend: submitted plus any injected delay.
    pub ready_ns: u64,
}

/// A frame that went over the wire.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Delivery {
    pub frame: Frame,
    pub station: u32,
    pub submitted_ns: u64,
    pub start_ns: u64,
    pub end_ns: u64,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct WireCounters {
    pub delivered: u64,
    /// Lost to a full queue.
    pub lost: u64,
    /// From silenced stations, never sent.
    pub silenced: u64,
    pub error_frames: u64,
    /// Bus time used, ns.
    pub busy_ns: u64,
}

#[derive(Debug, Clone, Copy)]
pub struct Wire {
    bitrate: u32,
    pending: [Option<Pending>; PENDING],
    on_wire: Option<(Pending, u64, u64, bool)>,
    free_at_ns: u64,
    silenced: [Option<u32>; SILENCED],
    delay: Option<(u16, u64)>,
    corrupt_next: u32,
    /// Bus-off: nothing crosses until the controllers restart.
    off: bool,
    counters: WireCounters,
}

/// Lower wins arbitration: the arbitration field's bits as a number,
/// dominant (0) first.
pub(crate) fn arbitration_key(frame: &Frame) -> u64 {
    let remote = u64::from(frame.is_remote());
    if frame.is_extended() {
        let base = u64::from(frame.id >> 18) & 0x7FF;
        let extension = u64::from(frame.id) & 0x3FFFF;
        (base << 21) | (1 << 20) | (1 << 19) | (extension << 1) | remote
    } else {
        ((u64::from(frame.id) & 0x7FF) << 21) | (remote << 20)
    }
}

impl Wire {
    pub fn new(bitrate: u32) -> Self {
        Self {
            bitrate: bitrate.max(1),
            pending: [None; PENDING],
            on_wire: None,
            free_at_ns: 0,
            silenced: [None; SILENCED],
            delay: None,
            corrupt_next: 0,
            off: false,
            counters: WireCounters::default(),
        }
    }

    pub fn counters(&self) -> WireCounters {
        self.counters
    }

    /// Frames of `station` are no longer sent (its transceiver is cut).
    pub fn silence(&mut self, station: u32) {
        if self.silenced.contains(&Some(station)) {
            return;
        }
        if let Some(slot) = self.silenced.iter_mut().find(|s| s.is_none()) {
            *slot = Some(station);
        }
    }

    pub fn restore(&mut self, station: u32) {
        for slot in &mut self.silenced {
            if *slot == Some(station) {
                *slot = None;
            }
        }
    }

    pub(crate) fn is_silenced(&self, station: u32) -> bool {
        self.silenced.contains(&Some(station))
    }

    /// Frames with `cob_id` wait `delay_ns` before they contend; `None`
    /// ends the delay.
    pub fn delay(&mut self, delay: Option<(u16, u64)>) {
        self.delay = delay;
    }

    /// The next `count` transmissions are destroyed by an error frame and
    /// sent again.
    pub fn corrupt(&mut self, count: u32) {
        self.corrupt_next = self.corrupt_next.saturating_add(count);
    }

    /// The bus goes off (a short, a broken transceiver): what is waiting
    /// and what is handed over until [`Wire::restart`] is lost. Returns the
    /// error frame every station's controller reports.
    pub fn go_bus_off(&mut self) -> Frame {
        self.off = true;
        self.counters.lost += self.pending.iter().flatten().count() as u64;
        self.pending = [None; PENDING];
        self.on_wire = None;
        self.counters.error_frames += 1;
        Frame::error(crate::error_class::BUS_OFF, [0; 8])
    }

    /// The controllers restart after bus-off; the error frame they report.
    pub fn restart(&mut self) -> Frame {
        self.off = false;
        Frame::error(crate::error_class::RESTARTED, [0; 8])
    }

    /// A station hands a frame to its controller at `now_ns`.
    pub fn submit(&mut self, frame: Frame, station: u32, now_ns: u64) {
        if self.off {
            self.counters.lost += 1;
            return;
        }
        if self.is_silenced(station) {
            self.counters.silenced += 1;
            return;
        }
        let ready_ns = match self.delay {
            Some((id, delay)) if !frame.is_extended() && frame.id == u32::from(id) => now_ns + delay,
            _ => now_ns,
        };
        match self.pending.iter_mut().find(|p| p.is_none()) {
            Some(slot) => {
                *slot = Some(Pending {
                    frame,
                    station,
                    submitted_ns: now_ns,
                    ready_ns,
                })
            }
            None => self.counters.lost += 1,
        }
    }

    /// When something next happens on the wire: a transmission ends or a
    /// waiting frame starts.
    pub fn next_event_ns(&self) -> Option<u64> {
        if let Some((_, _, end, _)) = self.on_wire {
            return Some(end);
        }
        self.pending
            .iter()
            .flatten()
            .map(|p| p.ready_ns.max(self.free_at_ns))
            .min()
    }

    /// Advances the wire to `now_ns` and returns the next frame that has
    /// finished by then (an error frame for a corrupted transmission);
    /// call again until `None`.
    pub fn poll(&mut self, now_ns: u64) -> Option<Delivery> {
        loop {
            if let Some((pending, start, end, corrupted)) = self.on_wire {
                if end > now_ns {
                    return None;
                }
                self.on_wire = None;
                self.free_at_ns = end;
                self.counters.busy_ns += end - start;
                if corrupted {
                    self.counters.error_frames += 1;
                    // The sender retries: the frame contends again at once.
                    self.put_back(Pending {
                        ready_ns: end,
                        ..pending
                    });
                    return Some(Delivery {
                        frame: Frame::error(ERROR_CLASS_PROTOCOL, [0; 8]),
                        station: pending.station,
                        submitted_ns: pending.submitted_ns,
                        start_ns: start,
                        end_ns: end,
                    });
                }
                self.counters.delivered += 1;
                return Some(Delivery {
                    frame: pending.frame,
                    station: pending.station,
                    submitted_ns: pending.submitted_ns,
                    start_ns: start,
                    end_ns: end,
                });
            }
            if !self.start_next(now_ns) {
                return None;
            }
        }
    }

    /// Starts the winner among the frames ready when the bus frees (or,
    /// if none is, when the first becomes ready), if that is by `now_ns`.
    fn start_next(&mut self, now_ns: u64) -> bool {
        let Some(first_ready) = self.pending.iter().flatten().map(|p| p.ready_ns).min() else {
            return false;
        };
        let start = first_ready.max(self.free_at_ns);
        if start > now_ns {
            return false;
        }
        let winner = self
            .pending
            .iter()
            .enumerate()
            .filter_map(|(i, p)| p.filter(|p| p.ready_ns <= start).map(|p| (i, p)))
            .min_by_key(|(_, p)| (arbitration_key(&p.frame), p.submitted_ns));
        let Some((index, pending)) = winner else {
            return false;
        };
        self.pending[index] = None;
        let corrupted = self.corrupt_next > 0;
        let bits = if corrupted {
            self.corrupt_next -= 1;
            // Destroyed somewhere in the frame; here at its end, the
            // longest the bus can lose.
            frame_bits(&pending.frame) + ERROR_FRAME_BITS
        } else {
            frame_bits(&pending.frame)
        };
        self.on_wire = Some((pending, start, start + bus_time_ns(bits, self.bitrate), corrupted));
        true
    }

    fn put_back(&mut self, pending: Pending) {
        match self.pending.iter_mut().find(|p| p.is_none()) {
            Some(slot) => *slot = Some(pending),
            None => self.counters.lost += 1,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(id: u16, len: usize) -> Frame {
        Frame::new(id, &[0x55; 8][..len]).expect("frame")
    }

    fn drain(wire: &mut Wire, until: u64) -> Vec<Delivery> {
        let mut out = Vec::new();
        while let Some(d) = wire.poll(until) {
            out.push(d);
        }
        out
    }

    #[test]
    fn the_lowest_id_wins_and_each_frame_takes_its_bits() {
        let mut wire = Wire::new(1_000_000);
        for id in [0x310, 0x080, 0x1A0, 0x210] {
            wire.submit(frame(id, 4), 1, 0);
        }
        let delivered = drain(&mut wire, 10_000_000);
        let ids: Vec<u32> = delivered.iter().map(|d| d.frame.id).collect();
        assert_eq!(ids, [0x080, 0x1A0, 0x210, 0x310]);
        for pair in delivered.windows(2) {
            assert_eq!(pair[1].start_ns, pair[0].end_ns, "back to back");
        }
        let first = delivered[0];
        assert_eq!(
            first.end_ns - first.start_ns,
            u64::from(frame_bits(&first.frame)) * 1000
        );
        assert_eq!(wire.counters().delivered, 4);
    }

    #[test]
    fn a_frame_submitted_while_the_bus_is_busy_waits_and_then_contends() {
        let mut wire = Wire::new(500_000);
        wire.submit(frame(0x700, 8), 1, 0);
        // The higher priority one comes while 0x700 is on the wire: it
        // waits for the end, it does not preempt.
        wire.submit(frame(0x001, 0), 2, 10_000);
        wire.submit(frame(0x002, 0), 3, 10_000);
        let delivered = drain(&mut wire, 1_000_000);
        let ids: Vec<u32> = delivered.iter().map(|d| d.frame.id).collect();
        assert_eq!(ids, [0x700, 0x001, 0x002]);
        assert!(drain(&mut wire, 2_000_000).is_empty());
        assert_eq!(wire.next_event_ns(), None);
    }

    #[test]
    fn standard_beats_extended_and_data_beats_remote() {
        let standard = Frame::new(0x123, &[]).expect("frame");
        let extended = Frame::extended(0x123 << 18, &[]).expect("frame");
        let remote = Frame::remote(0x123, 0).expect("frame");
        assert!(arbitration_key(&standard) < arbitration_key(&remote));
        assert!(arbitration_key(&remote) < arbitration_key(&extended));
        assert!(arbitration_key(&Frame::extended(0x122 << 18, &[]).expect("frame")) < arbitration_key(&standard));
    }

    #[test]
    fn nothing_is_delivered_before_its_time() {
        let mut wire = Wire::new(1_000_000);
        wire.submit(frame(0x181, 4), 1, 1_000);
        assert_eq!(wire.poll(1_000), None, "still on the wire");
        let end = wire.next_event_ns().expect("on the wire");
        assert!(end > 1_000 + 79_000 - 1);
        assert_eq!(wire.poll(end).map(|d| d.frame.id), Some(0x181));
    }

    #[test]
    fn silenced_delayed_and_corrupted() {
        let mut wire = Wire::new(1_000_000);
        wire.silence(7);
        wire.submit(frame(0x190, 4), 7, 0);
        assert!(drain(&mut wire, 1_000_000).is_empty());
        assert_eq!(wire.counters().silenced, 1);
        wire.restore(7);
        wire.delay(Some((0x190, 300_000)));
        wire.submit(frame(0x190, 4), 7, 1_000_000);
        wire.submit(frame(0x1A0, 4), 8, 1_000_000);
        let delivered = drain(&mut wire, 2_000_000);
        assert_eq!(delivered[0].frame.id, 0x1A0, "the delayed one waits");
        assert!(delivered[1].start_ns >= 1_300_000);
        wire.delay(None);
        wire.corrupt(1);
        wire.submit(frame(0x210, 4), 9, 3_000_000);
        let delivered = drain(&mut wire, 4_000_000);
        assert!(delivered[0].frame.is_error());
        assert_eq!(delivered[1].frame.id, 0x210, "sent again");
        assert_eq!(wire.counters().error_frames, 1);
    }

    #[test]
    fn a_full_queue_loses_and_counts() {
        let mut wire = Wire::new(10_000);
        for _ in 0..PENDING + 3 {
            wire.submit(frame(0x300, 8), 1, 0);
        }
        assert_eq!(wire.counters().lost, 3);
    }
}
