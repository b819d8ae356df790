//! What the tests on the virtual CAN bus share: the devices' COB-IDs in
//! `config/can.toml`, a config written over it, and a station of the
//! test's own that hears every frame.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;

use hydractl_bus::{Bus, RunScope};
use hydractl_can::valve::DeviceState;
use hydractl_can::Frame;
use hydractl_canio::{CanPort, VirtualCanPort};

pub const VALVE_SET_POINT: u32 = 0x210;
pub const VALVE_STATUS: u32 = 0x190;
pub const VALVE_EMCY: u32 = 0x090;
/// The control word's RPDO (0x6040, and the device mode).
pub const VALVE_CONTROL: u32 = 0x310;

/// `config/<name>` with `extra` TOML over it, written to `dir`. Lost after
/// 50 periods, not 10: on a loaded 2-core machine a process among
/// fourteen can stall for 10 ms.
pub fn can_config(dir: &Path, name: &str, extra: &str) -> PathBuf {
    let base = Path::new(env!("CARGO_MANIFEST_DIR")).join("../config").join(name);
    let path = dir.join(name);
    std::fs::write(
        &path,
        format!(
            "base = {:?}\n[supervisor]\nmachine_lost_after_periods = 50\n{extra}",
            base.display().to_string()
        ),
    )
    .expect("config");
    path
}

/// Every frame on the virtual bus `vcan0` with the time its last bit
/// crossed, heard by a station of the test's own.
pub struct BusTap {
    stop: Arc<AtomicBool>,
    thread: std::thread::JoinHandle<Vec<(u64, Frame)>>,
}

impl BusTap {
    pub fn start(scope: &RunScope) -> Self {
        let stop = Arc::new(AtomicBool::new(false));
        let (scope, flag) = (scope.clone(), stop.clone());
        let (ready_tx, ready_rx) = std::sync::mpsc::channel();
        let thread = std::thread::spawn(move || {
            let bus = Bus::open(&scope, "bustap").expect("node");
            let port = VirtualCanPort::monitor(&bus, "vcan0").expect("tap");
            ready_tx.send(()).expect("ready");
            let mut frames = Vec::new();
            while !flag.load(Ordering::Relaxed) {
                while let Some(r) = port.receive().expect("receive") {
                    frames.push((r.time_ns, r.frame));
                }
                std::thread::sleep(Duration::from_millis(1));
            }
            frames
        });
        ready_rx.recv_timeout(Duration::from_secs(10)).expect("tap open");
        Self { stop, thread }
    }

    pub fn finish(self) -> Vec<(u64, Frame)> {
        self.stop.store(true, Ordering::Relaxed);
        self.thread.join().expect("tap")
    }
}

pub fn status_of(frame: &Frame) -> DeviceState {
    DeviceState::from_status_word(u16::from_le_bytes([frame.data[0], frame.data[1]]), true)
}

pub fn set_point_of(frame: &Frame) -> i16 {
    i16::from_le_bytes([frame.data[2], frame.data[3]])
}
