//! What the vehicle computer needs of a run: locked memory and no page
//! fault on the loop.

use std::collections::BTreeMap;
use std::path::Path;
use std::time::Duration;

use hydractl_system_tests::*;

/// Whether this process may lock all its memory: root, or an unlimited
/// `RLIMIT_MEMLOCK` (the unit's `LimitMEMLOCK=infinity`).
fn may_lock_memory() -> bool {
    use nix::sys::resource::{getrlimit, Resource, RLIM_INFINITY};
    nix::unistd::geteuid().is_root() || getrlimit(Resource::RLIMIT_MEMLOCK).is_ok_and(|(soft, _)| soft == RLIM_INFINITY)
}

#[test]
fn a_fifteen_second_run_takes_no_page_fault_on_the_loop() {
    let _turn = serial();
    let scope = unique_scope("pagefaults");
    let dir = scratch_dir("pagefaults");
    let config = Path::new(env!("CARGO_MANIFEST_DIR")).join("../config/sim.toml");
    let summary = run_config_for(&scope, &dir, &config, "15");
    let processes = summary["processes"].as_array().expect("processes");
    for name in PIPELINE_PROCESSES {
        let p = processes
            .iter()
            .find(|p| p["name"] == name)
            .unwrap_or_else(|| panic!("{name} in {summary}"));
        assert_eq!(p["page_faults_after_start"], 0, "{name}: {p}");
        if may_lock_memory() {
            assert_eq!(p["memory_locked"], true, "{name}: {p}");
        }
    }
    // The supervisor has no loop: nothing is counted for it.
    let supervisor = processes
        .iter()
        .find(|p| p["name"] == "supervisor")
        .expect("supervisor");
    assert!(supervisor["page_faults_after_start"].is_null(), "{supervisor}");
    assert!(summary["cycles"].as_u64().expect("cycles") >= 14_500, "{summary}");
}

/// A tmpfs of `size` mounted at `dir` for a test, unmounted when dropped:
/// a small disk that fills for certain.
struct SmallDisk(std::path::PathBuf);

impl SmallDisk {
    fn mount(dir: &Path, size: &str) -> Self {
        std::fs::create_dir_all(dir).expect("mount point");
        let out = std::process::Command::new("mount")
            .args(["-t", "tmpfs", "-o", &format!("size={size}"), "tmpfs"])
            .arg(dir)
            .output()
            .expect("mount runs");
        assert!(
            out.status.success(),
            "mounting a {size} tmpfs at {} (needs root, as .ci/run has): {}",
            dir.display(),
            String::from_utf8_lossy(&out.stderr)
        );
        Self(dir.to_path_buf())
    }
}

impl Drop for SmallDisk {
    fn drop(&mut self) {
        let _ = std::process::Command::new("umount").arg(&self.0).status();
    }
}

#[test]
fn a_recording_onto_a_full_disk_stops_once_says_what_it_lost_and_the_loop_holds() {
    let _turn = serial();
    let scope = unique_scope("diskfull");
    let dir = scratch_dir("diskfull");
    let disk = SmallDisk::mount(&dir.join("small"), "1m");
    let (file, summary_path) = (disk.0.join("run.mcap"), dir.join("summary.json"));
    let witness = Witness::in_background(&scope);
    let out = run_to_end(
        &scope,
        &[
            "--duration",
            "8",
            "--record",
            file.to_str().expect("path"),
            "--summary-json",
            summary_path.to_str().expect("path"),
        ],
        std::time::Duration::from_secs(60),
    );
    let seen = witness.finish();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(
        out.status.code(),
        Some(3),
        "the run says its recording is incomplete: {stderr}"
    );
    assert_eq!(
        stderr.matches("the disk is full").count(),
        1,
        "said once, by the recorder: {stderr}"
    );
    assert!(stderr.contains("the recording is INCOMPLETE"), "{stderr}");
    let summary = read_json(&summary_path);
    let recording = &summary["recording"];
    assert_eq!(recording["complete"], false, "{recording}");
    assert_eq!(recording["recorder_restarts"], 0, "never crash-loops: {recording}");
    assert_eq!(recording["files"].as_array().map(Vec::len), Some(1), "{recording}");
    assert!(recording["disk_full"].as_u64() >= Some(1), "{recording}");
    // The loop did not notice: it ran its eight seconds at its rate. The
    // simulated plant pauses while this machine takes its CPU away (7694
    // cycles, no deadline missed, in one full suite here): 90 % of them.
    assert!(summary["cycles"].as_u64() >= Some(7_200), "{summary}");
    let restarts: u64 = summary["processes"]
        .as_array()
        .expect("processes")
        .iter()
        .map(|p| p["restarts"].as_u64().unwrap_or(0))
        .sum();
    assert_eq!(restarts, 0, "{summary}");

    // Exactly what is missing: on every loop service, what was recorded is
    // everything published up to a cut, and nothing after it; the samples
    // after the cut are counted in `not_recorded` (which also counts the
    // statuses, a few dozen a second, that the witness does not watch).
    let recorded = recorded_sequences(&file);
    let mut unrecorded_on_the_loop = 0u64;
    for topic in PIPELINE_SERVICES {
        let (seen, held) = (&seen[topic], &recorded[topic]);
        let last_held = *held.last().expect("some of it recorded");
        let before_cut: std::collections::BTreeSet<u64> = seen.range(..=last_held).copied().collect();
        let missing_before_cut: Vec<&u64> = before_cut.difference(held).take(5).collect();
        assert!(
            missing_before_cut.is_empty(),
            "{topic}: a hole before the cut: {missing_before_cut:?}"
        );
        unrecorded_on_the_loop += seen.range(last_held + 1..).count() as u64;
    }
    let not_recorded = recording["not_recorded"]["samples"]
        .as_u64()
        .expect("not_recorded.samples");
    let after_cut_s = 8.0 - recording["not_recorded"]["from_s"].as_f64().expect("from_s");
    assert!(after_cut_s > 1.0 && after_cut_s < 7.5, "{recording}");
    assert!(
        not_recorded >= unrecorded_on_the_loop
            && not_recorded <= unrecorded_on_the_loop + (60.0 * (after_cut_s + 2.0)) as u64,
        "not_recorded {not_recorded}, of which {unrecorded_on_the_loop} on the loop's services after the cut at {} s",
        8.0 - after_cut_s
    );
    drop(disk);
}

#[test]
fn a_ring_of_split_files_stays_within_keep_mb_for_a_run_five_times_longer() {
    let _turn = serial();
    let scope = unique_scope("ring");
    let dir = scratch_dir("ring");
    let ring = dir.join("ring");
    std::fs::create_dir_all(&ring).expect("ring dir");
    let (file, summary_path) = (ring.join("run.mcap"), dir.join("summary.json"));
    const KEEP_BYTES: u64 = 400_000;
    const SECONDS: u64 = 16;
    let mut run = start_run(
        &scope,
        &[
            "--duration",
            &SECONDS.to_string(),
            "--record",
            file.to_str().expect("path"),
            "--split-size-mb",
            "0.1",
            "--keep-mb",
            "0.4",
            "--summary-json",
            summary_path.to_str().expect("path"),
        ],
    );
    // Each part's largest size seen: what reached the disk, at least.
    let mut seen: std::collections::BTreeMap<std::path::PathBuf, u64> = Default::default();
    let look = |seen: &mut std::collections::BTreeMap<std::path::PathBuf, u64>| -> u64 {
        let mut on_disk = 0;
        for entry in std::fs::read_dir(&ring).expect("ring").filter_map(Result::ok) {
            let len = entry.metadata().map_or(0, |m| m.len());
            on_disk += len;
            let largest = seen.entry(entry.path()).or_default();
            *largest = (*largest).max(len);
        }
        on_disk
    };
    let mut largest = 0u64;
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(60);
    while run.0.try_wait().expect("wait").is_none() {
        assert!(std::time::Instant::now() < deadline, "the run ends");
        largest = largest.max(look(&mut seen));
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    assert!(wait_exit(&mut run.0, std::time::Duration::from_secs(1)).success());
    largest = largest.max(look(&mut seen));
    let summary = read_json(&summary_path);
    let recording = &summary["recording"];
    assert!(
        largest <= KEEP_BYTES,
        "the ring held {largest} bytes at most, over its {KEEP_BYTES}"
    );
    let kept = recording["files"].as_array().expect("files");
    assert!(
        kept.len() >= 2,
        "a ring of 0.1 MB parts in 0.4 MB holds more than one: {recording}"
    );
    let written: u64 = seen.values().sum();
    assert!(
        written >= 5 * KEEP_BYTES,
        "a run five times longer than the ring: {written} bytes over {recording}"
    );
    assert_eq!(
        recording["complete"], true,
        "deleting by design loses nothing unsaid: {recording}"
    );
    // The ring holds the run's end. Not necessarily the newest part alone:
    // a part opened in the run's last milliseconds may hold no valve
    // sample yet.
    let last_valve = kept
        .iter()
        .filter_map(|f| f.as_str())
        .filter_map(|part| {
            recorded_sequences(Path::new(part))
                .get(hydractl_samples::service::VALVE)
                .and_then(|held| held.last().copied())
        })
        .max();
    assert!(
        last_valve >= Some((SECONDS - 1) * 1000),
        "the ring's last valve sample is {last_valve:?}: {recording}"
    );
}

/// The journal's socket for a test, when no journald listens: removed
/// when dropped, with the folders it made.
struct FakeJournal {
    socket: std::os::unix::net::UnixDatagram,
    made: Vec<std::path::PathBuf>,
}

impl FakeJournal {
    const PATH: &'static str = "/run/systemd/journal/socket";

    fn open() -> Option<Self> {
        let path = Path::new(Self::PATH);
        if path.exists() {
            return None;
        }
        let made: Vec<std::path::PathBuf> = path
            .ancestors()
            .skip(1)
            .filter(|d| !d.exists())
            .map(Path::to_path_buf)
            .collect();
        std::fs::create_dir_all(path.parent().expect("parent")).ok()?;
        let socket = std::os::unix::net::UnixDatagram::bind(path).ok()?;
        socket
            .set_read_timeout(Some(std::time::Duration::from_millis(500)))
            .expect("timeout");
        Some(Self { socket, made })
    }

    /// Reads every entry as it comes, as journald does: a datagram socket
    /// nobody reads holds only `net.unix.max_dgram_qlen` (10) messages,
    /// and then blocks its senders. The entries come back when `stop` is
    /// set and the senders have fallen silent.
    fn drain(
        &self,
        stop: std::sync::Arc<std::sync::atomic::AtomicBool>,
    ) -> std::thread::JoinHandle<Vec<BTreeMap<String, String>>> {
        let socket = self.socket.try_clone().expect("journal socket");
        std::thread::spawn(move || {
            let mut entries = Vec::new();
            let mut buf = vec![0u8; 64 * 1024];
            loop {
                match socket.recv(&mut buf) {
                    Ok(0) => {}
                    Ok(n) => entries.push(journal_fields(&buf[..n])),
                    Err(_) if stop.load(std::sync::atomic::Ordering::Relaxed) => return entries,
                    Err(_) => {}
                }
            }
        })
    }
}

/// One entry of journald's native protocol: `KEY=value` lines, or `KEY`, a
/// newline, the value's length as a little-endian u64, the value, a newline
/// (for values that may hold newlines; tracing-journald sends most so).
fn journal_fields(mut datagram: &[u8]) -> BTreeMap<String, String> {
    let mut fields = BTreeMap::new();
    while let Some(end) = datagram.iter().position(|&b| b == b'\n' || b == b'=') {
        let key = String::from_utf8_lossy(&datagram[..end]).into_owned();
        if datagram[end] == b'=' {
            let line_end = datagram[end..]
                .iter()
                .position(|&b| b == b'\n')
                .map_or(datagram.len(), |n| end + n);
            fields.insert(key, String::from_utf8_lossy(&datagram[end + 1..line_end]).into_owned());
            datagram = &datagram[(line_end + 1).min(datagram.len())..];
        } else {
            let Some(length) = datagram.get(end + 1..end + 9) else {
                break;
            };
            let length = u64::from_le_bytes(length.try_into().expect("eight bytes")) as usize;
            let start = end + 9;
            let Some(value) = datagram.get(start..start + length) else {
                break;
            };
            fields.insert(key, String::from_utf8_lossy(value).into_owned());
            datagram = &datagram[(start + length + 1).min(datagram.len())..];
        }
    }
    fields
}

impl Drop for FakeJournal {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(Self::PATH);
        for dir in &self.made {
            let _ = std::fs::remove_dir(dir);
        }
    }
}

#[test]
fn as_a_service_every_process_logs_to_the_journal_with_its_fields() {
    use std::os::unix::fs::MetadataExt;
    let _turn = serial();
    let Some(journal) = FakeJournal::open() else {
        eprintln!(
            "SKIPPED: a journald listens on {} (read it with journalctl), or /run is not ours",
            FakeJournal::PATH
        );
        return;
    };
    let scope = unique_scope("journal");
    let dir = scratch_dir("journal");
    let stderr_path = dir.join("stderr");
    let stderr = std::fs::File::create(&stderr_path).expect("stderr file");
    let meta = stderr.metadata().expect("metadata");
    // As systemd sets it for a service whose output goes to the journal.
    let stream = format!("{}:{}", meta.dev(), meta.ino());
    let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let reader = journal.drain(stop.clone());
    let status = hydractl()
        .args(["run", "--duration", "0"])
        .env(hydractl_bus::PREFIX_ENV, scope.prefix())
        .env("JOURNAL_STREAM", &stream)
        .env("RUST_LOG", "info")
        .stdin(std::process::Stdio::null())
        .stdout(std::process::Stdio::null())
        .stderr(stderr)
        .status()
        .expect("hydractl run");
    stop.store(true, std::sync::atomic::Ordering::Relaxed);
    let entries = reader.join().expect("journal reader");
    assert!(status.success());
    let started_valve = entries
        .iter()
        .find(|e| e.get("MESSAGE").is_some_and(|m| m.starts_with("started valve")))
        .unwrap_or_else(|| panic!("the supervisor's start of the valve in the journal: {entries:#?}"));
    for (field, value) in [
        ("SYSLOG_IDENTIFIER", "supervisor"),
        ("PROCESS", "supervisor"),
        ("CHILD", "valve"),
        ("PRIORITY", "5"),
    ] {
        assert_eq!(
            started_valve.get(field).map(String::as_str),
            Some(value),
            "{started_valve:?}"
        );
    }
    assert!(
        started_valve
            .get("CHILD_PID")
            .is_some_and(|pid| pid.parse::<u32>().is_ok()),
        "{started_valve:?}"
    );
    let text = std::fs::read_to_string(&stderr_path).expect("stderr");
    assert!(
        !text.contains("started valve"),
        "the journal's lines are not written twice: {text}"
    );
}

#[test]
fn as_a_service_the_supervisor_says_ready_once_the_loop_runs_and_pings_the_watchdog() {
    use std::os::unix::net::UnixDatagram;
    let _turn = serial();
    let scope = unique_scope("notify");
    let dir = scratch_dir("notify");
    // As systemd sets it for `Type=notify`, `WatchdogSec=1`: the unit's
    // main process is `hydractl run`, whose pid WATCHDOG_PID names.
    let socket_path = dir.join("notify.sock");
    let socket = UnixDatagram::bind(&socket_path).expect("notify socket");
    socket
        .set_read_timeout(Some(Duration::from_millis(200)))
        .expect("timeout");
    let mut run = hydractl()
        .args(["run", "--duration", "3"])
        .env(hydractl_bus::PREFIX_ENV, scope.prefix())
        .env("NOTIFY_SOCKET", &socket_path)
        .env("WATCHDOG_USEC", "1000000")
        .env("WATCHDOG_PID", "1")
        .stdin(std::process::Stdio::null())
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .spawn()
        .expect("hydractl run");
    let mut messages = Vec::new();
    let deadline = std::time::Instant::now() + Duration::from_secs(30);
    let mut buffer = [0u8; 512];
    while std::time::Instant::now() < deadline {
        match socket.recv(&mut buffer) {
            Ok(n) => messages.push(String::from_utf8_lossy(&buffer[..n]).into_owned()),
            Err(_) if matches!(run.try_wait(), Ok(Some(_))) => break,
            Err(_) => {}
        }
    }
    let status = wait_exit(&mut run, Duration::from_secs(10));
    assert!(status.success());
    let ready: Vec<usize> = (0..messages.len())
        .filter(|&i| messages[i].lines().any(|l| l == "READY=1"))
        .collect();
    assert_eq!(ready.len(), 1, "one READY=1: {messages:?}");
    // Half the watchdog's second: about six pings in three seconds.
    let pings = messages.iter().filter(|m| m.lines().any(|l| l == "WATCHDOG=1")).count();
    assert!((4..=10).contains(&pings), "{pings} pings: {messages:?}");
    // Only the supervisor speaks: nothing but these two, and the status.
    assert!(
        messages
            .iter()
            .flat_map(|m| m.lines())
            .all(|l| l == "READY=1" || l == "WATCHDOG=1" || l.starts_with("STATUS=")),
        "{messages:?}"
    );
}
