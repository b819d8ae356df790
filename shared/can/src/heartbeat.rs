//! CiA 301's heartbeat: the producer time a master writes into each node,
//! and the master's watch of what each node last said (the heartbeat
//! consumer).

use crate::canopen::{decode_heartbeat, NmtState, NodeId, SdoRequest};
use crate::Frame;

/// Object 0x1017: the heartbeat producer time, ms (UNSIGNED16).
pub(crate) const HEARTBEAT_PRODUCER: u16 = 0x1017;

/// The master's SDO download of a node's heartbeat producer time.
pub fn set_heartbeat(node: NodeId, heartbeat_ms: u16) -> Frame {
    SdoRequest::Download {
        index: HEARTBEAT_PRODUCER,
        sub: 0,
        value: [heartbeat_ms.to_le_bytes()[0], heartbeat_ms.to_le_bytes()[1], 0, 0],
        len: 2,
    }
    .to_frame(node)
}

/// The master's view of a heartbeat: which state a node last reported and
/// when, and whether it has been silent too long (CiA 301's heartbeat
/// consumer).
#[derive(Debug, Clone, Copy)]
pub(crate) struct HeartbeatWatch {
    node: NodeId,
    timeout_ns: u64,
    last_ns: Option<u64>,
    state: Option<NmtState>,
}

impl HeartbeatWatch {
    pub fn new(node: NodeId, timeout_ms: u16) -> Self {
        Self {
            node,
            timeout_ns: u64::from(timeout_ms) * 1_000_000,
            last_ns: None,
            state: None,
        }
    }

    /// Takes the node's heartbeat; false for any other frame.
    pub fn on_frame(&mut self, frame: &Frame, now_ns: u64) -> bool {
        match decode_heartbeat(frame) {
            Ok((node, state)) if node == self.node => {
                self.last_ns = Some(now_ns);
                self.state = Some(state);
                true
            }
            _ => false,
        }
    }

    pub fn state(&self) -> Option<NmtState> {
        self.state
    }

    /// Heard once, and not for longer than the timeout since: lost. A node
    /// never heard is not lost, only not there yet.
    pub fn lost(&self, now_ns: u64) -> bool {
        self.last_ns.is_some_and(|t| now_ns.saturating_sub(t) > self.timeout_ns)
    }
}
