//! What one period's frames take of the bus: each frame's bits at
//! worst-case stuffing, the heartbeats spread over the periods, against
//! `[can] max_bus_load` (`hydractl can budget`, and the config's check).

use serde::Serialize;

use crate::profile::Profile;
use crate::timing;

/// One frame of a period's budget.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct BudgetLine {
    pub frame: String,
    pub cob_id: u16,
    pub bytes: u8,
    /// Without stuffing and at worst-case stuffing, intermission included.
    pub bits_min: u32,
    pub bits_max: u32,
    pub time_max_us: f64,
}

/// What one period's frames take of the bus.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Budget {
    pub bitrate: u32,
    pub period_us: f64,
    pub frames: Vec<BudgetLine>,
    /// Heartbeats of every node, spread over the periods.
    pub heartbeat_bits_per_period: f64,
    pub time_max_us: f64,
    pub load_percent_max: f64,
    pub max_bus_load_percent: f64,
    pub fits: bool,
    /// The shortest period the frames fit at this bitrate, µs.
    pub shortest_period_us: f64,
}

impl Profile {
    /// The frames of one period: SYNC, the three sensors' TPDOs, the
    /// valve's set point and its answer.
    pub(crate) fn period_frames(&self) -> Vec<(String, u16, u8)> {
        vec![
            ("SYNC".to_string(), self.sync_cob_id, 0),
            (
                "encoder position TPDO".to_string(),
                self.encoder_position.cob_id,
                self.encoder_position.mapping.len() as u8,
            ),
            (
                "pressure_a TPDO".to_string(),
                self.pressure[0].value.cob_id,
                self.pressure[0].value.mapping.len() as u8,
            ),
            (
                "pressure_b TPDO".to_string(),
                self.pressure[1].value.cob_id,
                self.pressure[1].value.mapping.len() as u8,
            ),
            (
                "valve set point RPDO".to_string(),
                self.valve_set_point.cob_id,
                self.valve_set_point.mapping.len() as u8,
            ),
            (
                "valve status TPDO".to_string(),
                self.valve_status.cob_id,
                self.valve_status.mapping.len() as u8,
            ),
        ]
    }

    pub fn budget(&self, period_ns: u64) -> Budget {
        let period_us = period_ns as f64 / 1000.0;
        let frames: Vec<BudgetLine> = self
            .period_frames()
            .into_iter()
            .map(|(frame, cob_id, bytes)| {
                let bits_max = timing::worst_case_bits(bytes, false);
                BudgetLine {
                    frame,
                    cob_id,
                    bytes,
                    bits_min: timing::unstuffed_bits(bytes, false),
                    bits_max,
                    time_max_us: timing::bus_time_ns(bits_max, self.bitrate) as f64 / 1000.0,
                }
            })
            .collect();
        // Four nodes' one-byte heartbeats every heartbeat_ms.
        let heartbeat_bits_per_period =
            4.0 * f64::from(timing::worst_case_bits(1, false)) * period_us / (f64::from(self.heartbeat_ms) * 1000.0);
        let bits: f64 = frames.iter().map(|l| f64::from(l.bits_max)).sum::<f64>() + heartbeat_bits_per_period;
        let time_max_us = bits * 1e6 / f64::from(self.bitrate);
        let load_percent_max = 100.0 * time_max_us / period_us;
        Budget {
            bitrate: self.bitrate,
            period_us,
            heartbeat_bits_per_period,
            time_max_us,
            load_percent_max,
            max_bus_load_percent: 100.0 * self.max_bus_load,
            fits: load_percent_max <= 100.0 * self.max_bus_load,
            // Heartbeats hardly depend on the period; the frames do.
            shortest_period_us: time_max_us / self.max_bus_load,
            frames,
        }
    }
}

impl Budget {
    /// The budget as a table for a terminal or an error message.
    pub fn table(&self) -> String {
        let mut text = format!(
            "{:<24} {:>6} {:>5} {:>13} {:>9}\n",
            "frame", "COB-ID", "bytes", "bits", "time µs"
        );
        for line in &self.frames {
            text.push_str(&format!(
                "{:<24} {:>#6x} {:>5} {:>6}–{:<6} {:>9.1}\n",
                line.frame, line.cob_id, line.bytes, line.bits_min, line.bits_max, line.time_max_us
            ));
        }
        text.push_str(&format!(
            "heartbeats, spread over the periods: {:.1} bits a period\n\
             one period at {} bit/s: {:.1} µs of {:.1} µs, {:.1}% of the bus (at most {:.0}% allowed): {}\n\
             the shortest period these frames fit: {:.0} µs\n",
            self.heartbeat_bits_per_period,
            self.bitrate,
            self.time_max_us,
            self.period_us,
            self.load_percent_max,
            self.max_bus_load_percent,
            if self.fits { "fits" } else { "does not fit" },
            self.shortest_period_us,
        ));
        text
    }
}
