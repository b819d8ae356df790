//! The benchmarks that start processes run, report every transport, and
//! leave no iceoryx2 file behind.

use std::time::Duration;

use hydractl_system_tests::{hydractl, serial, wait_exit};

#[test]
fn bench_latency_reports_every_transport_and_leaves_no_files() {
    let _turn = serial();
    let mut child = hydractl()
        .args(["bench", "latency", "--duration", "0.3", "--rounds", "1"])
        .stdout(std::process::Stdio::piped())
        .spawn()
        .expect("starting hydractl bench latency");
    let pid = child.id();
    let mut stdout = child.stdout.take().expect("stdout");
    let status = wait_exit(&mut child, Duration::from_secs(60));
    let mut out = String::new();
    std::io::Read::read_to_string(&mut stdout, &mut out).expect("reading the report");
    assert!(status.success(), "bench latency failed:\n{out}");
    for transport in ["iceoryx2 ", "iceoryx2-sem ", "udp ", "calls "] {
        let row = out
            .lines()
            .find(|line| line.starts_with(transport))
            .unwrap_or_else(|| panic!("no row for {transport}:\n{out}"));
        let figures: Vec<f64> = row.split_whitespace().skip(1).filter_map(|f| f.parse().ok()).collect();
        // p50 ≤ p99 ≤ p99.9 ≤ max, all measured.
        assert!(figures.len() >= 5, "{row}");
        assert!(figures.windows(2).take(3).all(|w| w[0] <= w[1]), "{row}");
    }
    assert!(out.contains("iceoryx2 / udp: p50"), "{out}");
    // As deployed: the recorder, the supervisor and the monitor read every service.
    assert!(out.contains("3 observers per service"), "{out}");
    assert!(out.contains("slowest cycles"), "{out}");
    // The benchmark's runs are prefixed with its pid.
    let ours = |name: &str| {
        [format!("hbench{}_", pid % 100_000), format!("hbsem{}_", pid % 100_000)]
            .iter()
            .any(|prefix| name.contains(prefix.as_str()))
    };
    for dir in ["/dev/shm", "/tmp/iceoryx2"] {
        let left: Vec<String> = std::fs::read_dir(dir)
            .map(|entries| {
                entries
                    .filter_map(Result::ok)
                    .map(|e| e.file_name().to_string_lossy().into_owned())
                    .filter(|name| ours(name))
                    .collect()
            })
            .unwrap_or_default();
        assert!(left.is_empty(), "left in {dir}: {left:?}");
    }
}

#[test]
fn bench_latency_refuses_more_observers_than_a_service_takes() {
    let output = hydractl()
        .args(["bench", "latency", "--observers", "9"])
        .output()
        .expect("running hydractl bench latency");
    assert!(!output.status.success());
    let err = String::from_utf8_lossy(&output.stderr);
    assert!(err.contains("--observers 9"), "{err}");
}
