//! The virtual CAN bus end to end: the `canbus` process as the wire, and
//! stations that are ports in this test. Frames take their bus time at
//! the bitrate, the lowest ID wins when the bus frees, and every station
//! but the sender receives each frame once, through its filters.

use std::process::{Child, Command};
use std::time::{Duration, Instant};

use hydractl_bus::{Bus, OwnedScope, PREFIX_ENV};
use hydractl_can::timing::{bus_time_ns, frame_bits};
use hydractl_can::Frame;
use hydractl_canio::{CanPort, Filter, Received, VirtualCanPort};

const BITRATE: u32 = 50_000;

struct Wire(Child);

impl Drop for Wire {
    fn drop(&mut self) {
        let pid = nix::unistd::Pid::from_raw(self.0.id() as i32);
        let _ = nix::sys::signal::kill(pid, nix::sys::signal::Signal::SIGTERM);
        let _ = self.0.wait();
    }
}

fn receive_n(port: &VirtualCanPort, n: usize, within: Duration) -> Vec<Received> {
    let deadline = Instant::now() + within;
    let mut got = Vec::new();
    while got.len() < n && Instant::now() < deadline {
        match port.receive().expect("receive") {
            Some(frame) => got.push(frame),
            None => std::thread::sleep(Duration::from_micros(200)),
        }
    }
    got
}

#[test]
fn frames_cross_the_virtual_bus_in_arbitration_order_taking_their_bus_time() {
    let scope = OwnedScope::fresh(&format!("t{}_vcan_", std::process::id() % 100_000)).expect("prefix");
    let dir = std::env::temp_dir().join(format!("hydractl-vcan-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("dir");
    let config = dir.join("vcan.toml");
    let sim = concat!(env!("CARGO_MANIFEST_DIR"), "/../config/sim.toml");
    // 50 kbit/s: an eight-byte frame holds the bus for about 2.7 ms, time
    // enough to hand two more to the wire while it is busy; a period of
    // 50 ms leaves the budget room.
    std::fs::write(
        &config,
        format!(
            "base = {sim:?}\n[timing]\ncontrol_rate_hz = 20.0\n[can]\ninterface = \"vtest0\"\nbitrate = {BITRATE}\n"
        ),
    )
    .expect("config");
    let bus = Bus::open(&scope, "stations").expect("node");
    let sender = VirtualCanPort::open(&bus, "vtest0", &[]).expect("sender");
    let receiver = VirtualCanPort::open(
        &bus,
        "vtest0",
        &[Filter::exact(0x100), Filter::exact(0x300), Filter::exact(0x700)],
    )
    .expect("receiver")
    .with_station(7);
    let _wire = Wire(
        Command::new(env!("CARGO_BIN_EXE_canbus"))
            .arg("--config")
            .arg(&config)
            .env(PREFIX_ENV, scope.prefix())
            .spawn()
            .expect("canbus"),
    );
    // The wire is up when a frame comes back.
    let probe = Frame::new(0x700, &[0x05]).expect("frame");
    let deadline = Instant::now() + Duration::from_secs(10);
    loop {
        sender.send(&probe).expect("send");
        if !receive_n(&receiver, 1, Duration::from_millis(100)).is_empty() {
            break;
        }
        assert!(Instant::now() < deadline, "the wire never delivered");
    }
    std::thread::sleep(Duration::from_millis(50));
    while receiver.receive().expect("drain").is_some() {}

    let long = Frame::new(0x700, &[0xAA; 8]).expect("frame");
    let high = Frame::new(0x300, &[1, 2]).expect("frame");
    let low = Frame::new(0x100, &[3]).expect("frame");
    let filtered_out = Frame::new(0x200, &[4]).expect("frame");
    sender.send(&long).expect("send");
    std::thread::sleep(Duration::from_micros(300));
    sender.send(&high).expect("send");
    sender.send(&filtered_out).expect("send");
    sender.send(&low).expect("send");
    let got = receive_n(&receiver, 3, Duration::from_secs(5));
    let ids: Vec<u32> = got.iter().map(|r| r.frame.id).collect();
    assert_eq!(
        ids,
        [0x700, 0x100, 0x300],
        "the busy bus, then the lowest ID; 0x200 filtered"
    );
    assert_eq!(got[1].frame, low);
    // Each frame ended its own bus time after the one before (back to back).
    for (before, after) in got.iter().zip(&got[1..]) {
        let gap = after.time_ns - before.time_ns;
        let own = bus_time_ns(frame_bits(&after.frame), BITRATE);
        assert!(gap >= own, "{gap} ns < {own} ns");
    }
    let third = bus_time_ns(frame_bits(&filtered_out), BITRATE);
    let span = got[2].time_ns - got[1].time_ns;
    assert!(
        span >= third,
        "0x200 held the bus between them although filtered: {span} ns"
    );
    assert!(receiver.receive().expect("receive").is_none(), "each frame once");
    let late = VirtualCanPort::open(&bus, "vtest0", &[]).expect("late").with_station(9);
    assert!(
        receive_n(&late, 1, Duration::from_millis(100)).is_empty(),
        "a station that joins late does not get the last frame again"
    );
    drop(late);
    assert!(
        receive_n(&sender, 1, Duration::from_millis(100)).is_empty(),
        "a station does not hear itself"
    );
    drop((sender, receiver, bus));
    drop(_wire);
    scope.clean_stale().expect("clean");
    std::fs::remove_dir_all(dir).ok();
}
