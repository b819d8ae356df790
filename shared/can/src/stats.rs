//! What a listener on the bus makes of its traffic: load, frames per
//! period, the period's PDOs that did not come before the next SYNC,
//! EMCYs. (Whether a PDO came in time for its reading is the master's
//! judgement, on its own clock: the readings say it.) Fed
//! every frame with the time its last bit crossed; the bus time of each
//! frame is counted bit for bit ([`crate::timing::frame_bits`]).

use crate::canopen::{self, Emergency};
use crate::profile::Profile;
use crate::timing;
use crate::Frame;

/// The TPDOs every SYNC must bring: encoder, transducers A and B, valve status.
const PERIOD_PDOS: usize = 4;

#[derive(Debug, Clone)]
pub struct BusStats {
    bitrate: u32,
    sync_cob_id: u16,
    pdos: [u16; PERIOD_PDOS],
    /// Each one's length by its mapping.
    pdo_lens: [u8; PERIOD_PDOS],
    frames: u64,
    bits: u64,
    first_ns: Option<u64>,
    last_ns: u64,
    syncs: u64,
    /// The current period: its SYNC's time and the PDOs seen since.
    sync_ns: Option<u64>,
    seen: [bool; PERIOD_PDOS],
    lost_frames: u64,
    malformed_pdos: u64,
    emcys: u64,
    error_frames: u64,
}

/// The figures, as the run's summary reports them.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BusFigures {
    pub load_percent: f64,
    pub frames_per_period: f64,
    pub lost_frames: u64,
    /// A period's PDO of another length than its mapping's: refused by
    /// its receiver (CiA 301), so also lost.
    pub malformed_pdos: u64,
    pub error_frames: u64,
    pub emcy: u64,
}

impl BusStats {
    pub fn new(profile: &Profile) -> Self {
        Self {
            bitrate: profile.bitrate,
            sync_cob_id: profile.sync_cob_id,
            pdos: [
                profile.encoder_position.cob_id,
                profile.pressure[0].value.cob_id,
                profile.pressure[1].value.cob_id,
                profile.valve_status.cob_id,
            ],
            pdo_lens: [
                profile.encoder_position.mapping.len() as u8,
                profile.pressure[0].value.mapping.len() as u8,
                profile.pressure[1].value.mapping.len() as u8,
                profile.valve_status.mapping.len() as u8,
            ],
            malformed_pdos: 0,
            frames: 0,
            bits: 0,
            first_ns: None,
            last_ns: 0,
            syncs: 0,
            sync_ns: None,
            seen: [false; PERIOD_PDOS],
            lost_frames: 0,
            emcys: 0,
            error_frames: 0,
        }
    }

    /// One frame off the bus, `end_ns` when its last bit crossed.
    pub fn on_frame(&mut self, frame: &Frame, end_ns: u64) {
        if frame.is_error() {
            self.error_frames += 1;
            return;
        }
        self.frames += 1;
        self.bits += u64::from(timing::frame_bits(frame));
        self.first_ns.get_or_insert(end_ns);
        self.last_ns = self.last_ns.max(end_ns);
        if canopen::is_sync(frame, self.sync_cob_id) {
            self.close_period();
            self.syncs += 1;
            self.sync_ns = Some(end_ns);
            return;
        }
        if let Some(i) = self
            .pdos
            .iter()
            .position(|&id| u32::from(id) == frame.id && !frame.is_extended())
        {
            if frame.len != self.pdo_lens[i] || frame.is_remote() {
                self.malformed_pdos += 1;
            } else if self.sync_ns.is_some() {
                self.seen[i] = true;
            }
            return;
        }
        let emcy = matches!(
            canopen::cob_id::function(frame.id as u16),
            canopen::cob_id::Function::Emcy(_)
        ) && !frame.is_extended();
        if emcy && Emergency::decode(frame).is_ok_and(|(_, e)| e.code != canopen::emcy_code::NO_ERROR) {
            self.emcys += 1;
        }
    }

    /// A period ends at the next SYNC: what it did not bring was lost.
    fn close_period(&mut self) {
        if self.sync_ns.is_some() {
            self.lost_frames += self.seen.iter().filter(|s| !**s).count() as u64;
        }
        self.seen = [false; PERIOD_PDOS];
    }

    pub fn figures(&self) -> BusFigures {
        let span_s = self
            .first_ns
            .map_or(0.0, |first| self.last_ns.saturating_sub(first) as f64 * 1e-9);
        BusFigures {
            load_percent: if span_s > 0.0 {
                100.0 * self.bits as f64 / (f64::from(self.bitrate) * span_s)
            } else {
                0.0
            },
            frames_per_period: if self.syncs > 0 {
                self.frames as f64 / self.syncs as f64
            } else {
                0.0
            },
            lost_frames: self.lost_frames,
            malformed_pdos: self.malformed_pdos,
            error_frames: self.error_frames,
            emcy: self.emcys,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::profile::CanConfig;

    #[test]
    fn load_lost_and_emcys_are_counted_per_period() {
        let profile = CanConfig::default().resolve().expect("defaults");
        let mut stats = BusStats::new(&profile);
        let sync = canopen::sync(profile.sync_cob_id, None);
        // As the default mapping has them: the transducers' INT16, 2 bytes.
        let pdo = |id: u16| Frame::new(id, &[0; 4][..if id == 0x1B0 || id == 0x1B1 { 2 } else { 4 }]).expect("pdo");
        let us = 1000;
        // Period 1: all four.
        stats.on_frame(&sync, 0);
        for (i, id) in [0x1A0, 0x1B0, 0x1B1].into_iter().enumerate() {
            stats.on_frame(&pdo(id), (100 + 100 * i as u64) * us);
        }
        stats.on_frame(&pdo(0x190), 900 * us);
        // Period 2: the encoder's lost, an EMCY, an error frame.
        stats.on_frame(&sync, 1000 * us);
        stats.on_frame(&pdo(0x1B0), 1100 * us);
        // The encoder's, garbled to two bytes: refused, and lost.
        stats.on_frame(&Frame::new(0x1A0, &[1, 2]).expect("short"), 1150 * us);
        stats.on_frame(&pdo(0x1B1), 1200 * us);
        stats.on_frame(&pdo(0x190), 1300 * us);
        let emcy = Emergency::new(canopen::emcy_code::VALVE_RPDO_TIMEOUT, 0x11).to_frame(0x10);
        stats.on_frame(&emcy, 1400 * us);
        stats.on_frame(&Frame::error(0x04, [0; 8]), 1500 * us);
        stats.on_frame(&sync, 2000 * us);
        let f = stats.figures();
        assert_eq!(f.lost_frames, 1);
        assert_eq!(f.malformed_pdos, 1);
        assert_eq!(f.emcy, 1);
        assert_eq!(f.error_frames, 1);
        assert!((f.frames_per_period - 12.0 / 3.0).abs() < 1e-9, "{f:?}");
        assert!(f.load_percent > 10.0 && f.load_percent < 100.0, "{f:?}");
    }
}
