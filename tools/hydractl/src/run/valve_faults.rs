//! The machine's valve's latched faults and resets over a run, from the
//! valve process's `hydractl/valve/device`: the summary's `valve_faults`.

use hydractl_samples::{name_str, ValveDevice};
use serde::Serialize;

#[derive(Serialize, Clone, Debug, PartialEq)]
pub struct ValveFaultSummary {
    /// The EMCY's error code, or the stack's own (above 0xFFFF).
    pub code: u32,
    pub meaning: String,
    /// Seconds from the run's start to when the run saw it latched; a fault
    /// latched before the run (kept across a restart) is at 0 with
    /// `latched_before_run`.
    pub at_s: f64,
    pub latched_before_run: bool,
    /// When a person reset it, s from the run's start; null: still latched.
    pub reset_at_s: Option<f64>,
}

/// Follows the device's states: a latch that appears is a fault, one that
/// goes is its reset.
#[derive(Default)]
pub struct ValveFaults {
    pub faults: Vec<ValveFaultSummary>,
    /// The latched fault's start, as the device said it (ns since the Unix
    /// epoch): the same fault republished is not a new one.
    current: Option<u64>,
    seen_any: bool,
}

impl ValveFaults {
    /// A device state, `at_s` into the run.
    pub fn on_device(&mut self, d: &ValveDevice, at_s: f64) {
        let first = !self.seen_any;
        self.seen_any = true;
        match (d.latched != 0, self.current) {
            (true, Some(since)) if since == d.latched_since_unix_ns => {}
            (true, _) => {
                self.close(at_s);
                self.current = Some(d.latched_since_unix_ns);
                self.faults.push(ValveFaultSummary {
                    code: d.fault_code,
                    meaning: name_str(&d.meaning).to_owned(),
                    at_s: if first { 0.0 } else { at_s },
                    latched_before_run: first,
                    reset_at_s: None,
                });
            }
            (false, Some(_)) => self.close(at_s),
            (false, None) => {}
        }
    }

    fn close(&mut self, at_s: f64) {
        if self.current.take().is_some() {
            if let Some(last) = self.faults.last_mut() {
                last.reset_at_s = Some(at_s);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use hydractl_samples::fixed_name;

    fn latched(since: u64) -> ValveDevice {
        ValveDevice {
            latched: 1,
            fault_code: 0x81FF,
            latched_since_unix_ns: since,
            meaning: fixed_name("EMCY 0x81ff"),
            ..ValveDevice::default()
        }
    }

    #[test]
    fn a_fault_and_its_reset_are_one_entry_and_a_carried_fault_says_so() {
        let mut v = ValveFaults::default();
        v.on_device(&latched(7), 0.1);
        v.on_device(&latched(7), 0.2);
        v.on_device(&ValveDevice::default(), 3.0);
        v.on_device(&latched(9), 4.0);
        assert_eq!(v.faults.len(), 2);
        assert!(v.faults[0].latched_before_run);
        assert_eq!(v.faults[0].reset_at_s, Some(3.0));
        assert_eq!(v.faults[1].at_s, 4.0);
        assert_eq!(v.faults[1].reset_at_s, None);
        assert!(!v.faults[1].latched_before_run);
    }
}
