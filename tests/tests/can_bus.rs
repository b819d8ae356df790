//! The virtual CAN bus from the command line: a candump log written by
//! hand in can-utils' format (frames as a PVED-CC valve, a CiA 406
//! encoder and a CiA 404 transducer send them, an extended and a remote
//! frame, an error frame) replayed onto the bus with its timing and
//! dumped back, frame for frame.

use std::process::{Child, Command, Stdio};
use std::time::Duration;

use hydractl_bus::PREFIX_ENV;
use hydractl_can::candump;
use hydractl_system_tests::*;
use nix::sys::signal::Signal;

const LOG: &str = "\
(1700000000.000000) can0 080#
(1700000000.000150) can0 1A0#00200000
(1700000000.000300) can0 1B0#D204
(1700000000.001000) can0 210#00000020
(1700000000.005000) can0 710#05
(1700000000.010000) can0 090#FF81110000000000
(1700000000.020000) can0 18FEF100#FFFF00FFFFFFFFFF
(1700000000.021000) can0 620#R
(1700000000.030000) can0 20000004#0004000000000000
";

struct Stopped(Child);

impl Drop for Stopped {
    fn drop(&mut self) {
        signal(self.0.id(), Signal::SIGTERM);
        let _ = self.0.wait();
    }
}

fn wait_for_node(scope: &hydractl_bus::RunScope, name: &str) {
    let up = || {
        scope
            .live_node_names()
            .expect("nodes")
            .iter()
            .any(|n| n == name)
            .then_some(())
    };
    assert!(
        wait_for(Duration::from_secs(10), Duration::from_millis(20), up).is_some(),
        "{name} never came up"
    );
}

#[test]
fn a_candump_log_replayed_onto_the_virtual_bus_is_dumped_back_frame_for_frame() {
    let _turn = serial();
    let scope = unique_scope("candump");
    let dir = scratch_dir("candump");
    let log = dir.join("in.log");
    let out = dir.join("out.log");
    std::fs::write(&log, LOG).expect("log");

    // No bus yet: both commands say so.
    let none = hydractl_in(&scope, &["can", "replay", log.to_str().expect("path")]);
    assert_eq!(none.status.code(), Some(1));
    assert!(
        String::from_utf8_lossy(&none.stderr).contains("no virtual CAN bus is running"),
        "{}",
        String::from_utf8_lossy(&none.stderr)
    );

    let _wire = Stopped(
        Command::new(binary_dir().join("canbus"))
            .env(PREFIX_ENV, scope.prefix())
            .stdin(Stdio::null())
            .spawn()
            .expect("canbus"),
    );
    wait_for_node(&scope, "canbus");
    let dump = hydractl()
        .args(["can", "dump", "--duration", "3", "--log"])
        .arg(&out)
        .env(PREFIX_ENV, scope.prefix())
        .spawn()
        .expect("dump");
    wait_for_node(&scope, "candump");
    std::thread::sleep(Duration::from_millis(100));
    let replayed = hydractl_in(&scope, &["can", "replay", log.to_str().expect("path")]);
    assert!(
        replayed.status.success(),
        "{}",
        String::from_utf8_lossy(&replayed.stderr)
    );
    assert!(String::from_utf8_lossy(&replayed.stderr).contains("replayed 9 frames"));
    let dumped = dump.wait_with_output().expect("dump ends");
    assert!(dumped.status.success());

    let sent = candump::parse(LOG).expect("log");
    let got = candump::parse(&std::fs::read_to_string(&out).expect("dump")).expect("the dump is a candump log");
    let frames = |l: &[candump::LoggedFrame]| l.iter().map(|f| f.frame).collect::<Vec<_>>();
    assert_eq!(frames(&got), frames(&sent), "every frame, in order, unchanged");
    assert!(got.iter().all(|f| f.interface == "vcan0"));
    // The log's timing kept: each frame's offset from the first within
    // a few milliseconds (a sleep, a wake-up, its own bus time).
    for (s, g) in sent.iter().zip(&got) {
        let logged = (s.time_ns - sent[0].time_ns) as f64 / 1e6;
        let arrived = (g.time_ns - got[0].time_ns) as f64 / 1e6;
        assert!(
            (arrived - logged).abs() < 5.0,
            "{logged} ms logged, {arrived} ms dumped"
        );
    }

    // A bad line is named, and nothing is sent.
    let bad = dir.join("bad.log");
    std::fs::write(&bad, "(1.000000) can0 181#00\n(1.000100) can0 181#0\n").expect("log");
    let refused = hydractl_in(&scope, &["can", "replay", bad.to_str().expect("path")]);
    assert_eq!(refused.status.code(), Some(1));
    let stderr = String::from_utf8_lossy(&refused.stderr);
    assert!(
        stderr.contains("bad.log") && stderr.contains("candump line 2"),
        "{stderr}"
    );
}
