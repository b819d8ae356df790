//! A device's settings the master relies on, written by SDO and read back
//! before the device is trusted: the valve's own guard (its set point's
//! RPDO timeout) and its heartbeat producer time. Plain state driven by
//! the device's SDO answers and the clock; the caller sends the frames.
//!
//! A setting is written (expedited download), then read (upload) and
//! compared: a refusal (SDO abort), a value read back other than the one
//! written, or no answer after `ATTEMPTS` tries of `ANSWER_TIMEOUT_NS`
//! each is a [`CanError::Setting`] naming the node, the object and the value.

use crate::canopen::{abort_description, NodeId, SdoRequest, SdoResponse};
use crate::{CanError, Frame};

/// How long a node has to answer an SDO request: CiA 301 leaves it to the
/// application; the devices here answer within a millisecond.
pub(crate) const ANSWER_TIMEOUT_NS: u64 = 50_000_000;
/// Requests sent before a silent node is given up on.
pub(crate) const ATTEMPTS: u8 = 3;

/// One object to set, and what it is, in words.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Setting {
    pub index: u16,
    pub sub: u8,
    pub value: u16,
    /// "the set point's RPDO timeout", with the unit after the value.
    pub what: &'static str,
    pub unit: &'static str,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Step {
    Write,
    Read,
}

/// Writes each setting in turn and reads it back.
#[derive(Debug, Clone)]
pub(crate) struct SettingsCheck<const N: usize> {
    node: NodeId,
    settings: [Setting; N],
    current: usize,
    step: Step,
    /// When the pending request went out, and how many times it has.
    sent_ns: Option<u64>,
    attempts: u8,
    failed: Option<CanError>,
}

impl<const N: usize> SettingsCheck<N> {
    pub fn new(node: NodeId, settings: [Setting; N]) -> Self {
        Self {
            node,
            settings,
            current: 0,
            step: Step::Write,
            sent_ns: None,
            attempts: 0,
            failed: None,
        }
    }

    /// Every setting written and read back as written.
    pub fn verified(&self) -> bool {
        self.current == N && self.failed.is_none()
    }

    /// The reason the device is not to be trusted, once there is one.
    pub fn failed(&self) -> Option<&CanError> {
        self.failed.as_ref()
    }

    /// The request due at `now_ns`: the next one, or the pending one again
    /// when its answer is overdue. `None` while waiting, once done, or once
    /// failed (a node silent after [`ATTEMPTS`] requests fails the check).
    pub fn due(&mut self, now_ns: u64) -> Option<Frame> {
        if self.current == N || self.failed.is_some() {
            return None;
        }
        if let Some(sent) = self.sent_ns {
            if now_ns.saturating_sub(sent) < ANSWER_TIMEOUT_NS {
                return None;
            }
            if self.attempts >= ATTEMPTS {
                self.fail(format!(
                    "no answer to {} requests of {} ms each",
                    ATTEMPTS,
                    ANSWER_TIMEOUT_NS / 1_000_000
                ));
                return None;
            }
        }
        self.sent_ns = Some(now_ns);
        self.attempts += 1;
        let s = self.settings[self.current];
        let request = match self.step {
            Step::Write => SdoRequest::Download {
                index: s.index,
                sub: s.sub,
                value: [s.value.to_le_bytes()[0], s.value.to_le_bytes()[1], 0, 0],
                len: 2,
            },
            Step::Read => SdoRequest::Upload {
                index: s.index,
                sub: s.sub,
            },
        };
        Some(request.to_frame(self.node))
    }

    /// The node's SDO answer. Answers for other objects (another client's,
    /// or a late one) are ignored.
    pub fn on_response(&mut self, response: SdoResponse) {
        if self.current == N || self.failed.is_some() || self.sent_ns.is_none() {
            return;
        }
        let s = self.settings[self.current];
        match (self.step, response) {
            (_, SdoResponse::Aborted { index, sub, code }) if (index, sub) == (s.index, s.sub) => {
                self.fail(format!("refused (SDO abort {code:#010x}: {})", abort_description(code)));
            }
            (Step::Write, SdoResponse::Downloaded { index, sub }) if (index, sub) == (s.index, s.sub) => {
                self.next(Step::Read);
            }
            (Step::Read, SdoResponse::Uploaded { index, sub, value, .. }) if (index, sub) == (s.index, s.sub) => {
                let read = u16::from_le_bytes([value[0], value[1]]);
                if read == s.value {
                    self.current += 1;
                    self.next(Step::Write);
                } else {
                    self.fail(format!("reads back {read} {} after the write", s.unit));
                }
            }
            _ => {}
        }
    }

    fn next(&mut self, step: Step) {
        self.step = step;
        self.sent_ns = None;
        self.attempts = 0;
    }

    fn fail(&mut self, reason: String) {
        let s = self.settings[self.current];
        self.failed = Some(CanError::Setting {
            node: self.node,
            index: s.index,
            sub: s.sub,
            what: s.what,
            value: format!("{} {}", s.value, s.unit),
            reason,
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: u64 = 1_000_000;
    const TIMEOUT: Setting = Setting {
        index: 0x1400,
        sub: 5,
        value: 20,
        what: "the set point's RPDO timeout",
        unit: "ms",
    };

    fn request(frame: Frame) -> SdoRequest {
        SdoRequest::decode(&frame).expect("an SDO request").1
    }

    #[test]
    fn a_setting_is_written_then_read_back() {
        let mut check = SettingsCheck::new(0x10, [TIMEOUT]);
        let write = check.due(0).expect("the write");
        assert!(matches!(
            request(write),
            SdoRequest::Download {
                index: 0x1400,
                sub: 5,
                value: [20, 0, 0, 0],
                len: 2
            }
        ));
        assert_eq!(check.due(MS), None, "waits for the answer");
        check.on_response(SdoResponse::Downloaded { index: 0x1400, sub: 5 });
        assert_eq!(
            request(check.due(2 * MS).expect("the read")),
            SdoRequest::Upload { index: 0x1400, sub: 5 }
        );
        check.on_response(SdoResponse::Uploaded {
            index: 0x1400,
            sub: 5,
            value: [20, 0, 0, 0],
            len: 2,
        });
        assert!(check.verified());
        assert_eq!(check.due(3 * MS), None);
    }

    #[test]
    fn a_refusal_a_different_value_or_silence_names_node_object_and_value() {
        let mut refused = SettingsCheck::new(0x10, [TIMEOUT]);
        refused.due(0);
        refused.on_response(SdoResponse::Aborted {
            index: 0x1400,
            sub: 5,
            code: 0x0602_0000,
        });
        let e = refused.failed().expect("refused").to_string();
        for part in ["0x10", "0x1400:5", "20 ms", "refused", "0x06020000"] {
            assert!(e.contains(part), "{part} in {e}");
        }

        let mut other = SettingsCheck::new(0x10, [TIMEOUT]);
        other.due(0);
        other.on_response(SdoResponse::Downloaded { index: 0x1400, sub: 5 });
        other.due(MS);
        other.on_response(SdoResponse::Uploaded {
            index: 0x1400,
            sub: 5,
            value: [100, 0, 0, 0],
            len: 2,
        });
        let e = other.failed().expect("another value").to_string();
        assert!(e.contains("reads back 100 ms"), "{e}");
        assert!(!other.verified());

        let mut silent = SettingsCheck::new(0x10, [TIMEOUT]);
        let mut sent = 0;
        for ms in 0..400 {
            sent += usize::from(silent.due(ms * MS).is_some());
        }
        assert_eq!(sent, usize::from(ATTEMPTS), "retried, then given up");
        assert!(silent.failed().expect("silent").to_string().contains("no answer"));
    }
}
