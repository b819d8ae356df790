//! Helpers for tests that start the real processes: where the binaries
//! are, a run under its own iceoryx2 prefix, and waiting on its status.
//!
//! What it holds: Tests that start the real processes: the shadow model
//! (`shadow`: `config/machine-drift.toml`'s valve overlap opening detected
//! and named a dead-zone of the right width, nothing raised on the unchanged
//! machine); the vehicle (`vehicle`: no page fault on the loop in 30 s, a
//! recording onto a full 1 MB disk, a ring within its limit; `package`: the
//! `.deb`'s contents, its unit under `systemd-analyze verify`, the installed
//! layout running the stack); a 10 s run against the offline simulation,
//! `kill -9` of each controller, Ctrl-C, a start over a killed run's files;
//! the valve path's safety (`valve_safety`: the valve neutral when stopped,
//! killed or restarted, a spinning controller, a limit-cycling baseline over
//! 60 s, a run of no duration); the stack on CAN (`can_stack`:
//! `config/can.toml` against the shared-memory stack, a silent encoder and
//! the fallback, `vehicle.toml` refused, the bus recorded frame for frame and
//! read by Python's and Foxglove's readers; `can_valve_faults`: a killed
//! valve process's fault latched across restarts of the process and the
//! stack, `valve reset` refused while the loop asks for travel and accepted
//! at neutral, the ramp after Active, bus-off, a stuck spool; `can_model`: a
//! CAN run's recording with a valve kill fitted and diagnosed, the stand-in's
//! friction named); the virtual CAN bus (`can_bus`: a hand-written candump
//! log of a valve's, an encoder's and a transducer's frames replayed onto the
//! bus and dumped back frame for frame, with its timing); recording (every
//! published sample recorded, checked by an independent subscriber and by the
//! Python `mcap` reader), a killed recorder, `record` attached to a run,
//! replay into a lone process; four hot swaps and back with no missed cycle,
//! refusals, `status --json`, restart rules, `SIGSTOP`, and a hundred `kill
//! -9`s accounted for in the summary.

pub mod can;
mod stall;
pub use stall::stall_report;

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::sync::{Mutex, MutexGuard};
use std::time::{Duration, Instant};

use hydractl_bus::{Bus, OwnedScope, Reader, RunScope, PREFIX_ENV};
use std::collections::{BTreeMap, BTreeSet};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

pub use hydractl_samples::service::{PIPELINE_PROCESSES, PIPELINE_SERVICES};
use hydractl_samples::{
    name_str, service, FrictionSample, PlantReading, PositionSample, Recordable, SensorSample, SupervisorStatus,
    TorqueSample, ValveSample,
};

/// The live stack pins its loop to one CPU; two runs at once would share
/// it, so the system tests take turns.
static SERIAL: Mutex<()> = Mutex::new(());

pub fn serial() -> MutexGuard<'static, ()> {
    SERIAL.lock().unwrap_or_else(|poisoned| poisoned.into_inner())
}

/// `target/<profile>/`, where cargo puts every binary of the workspace.
pub fn binary_dir() -> PathBuf {
    let exe = std::env::current_exe().expect("test executable");
    // target/<profile>/deps/<test> → target/<profile>/
    exe.parent().and_then(Path::parent).expect("target dir").to_path_buf()
}

/// `hydractl`, keeping what a run must keep across restarts (the valve's
/// latched fault) under [`state_dir`], a prefix's folder each.
pub fn hydractl() -> Command {
    let mut command = Command::new(binary_dir().join("hydractl"));
    command.env("HYDRACTL_STATE_DIR", state_dir());
    command
}

/// Where the tests' runs keep their state, one folder per prefix below.
pub fn state_dir() -> PathBuf {
    std::env::temp_dir().join("hydractl-test-state")
}

/// A run scope of a test's own, whose files are removed when it is dropped,
/// also when the test fails half-way. Declare it before the run's guard, so
/// that the run stops first.
pub struct ScopeGuard(OwnedScope);

impl std::ops::Deref for ScopeGuard {
    type Target = RunScope;
    fn deref(&self) -> &RunScope {
        &self.0
    }
}

impl Drop for ScopeGuard {
    fn drop(&mut self) {
        // The shared memory goes with the field, after this.
        let _ = std::fs::remove_dir_all(state_dir().join(self.0.prefix()));
    }
}

/// A prefix no other test or run uses.
pub fn unique_scope(test: &str) -> ScopeGuard {
    let prefix = format!("t{}_{}_", std::process::id() % 100_000, test);
    let scope = OwnedScope::fresh(&prefix).expect("valid prefix, clean start");
    // What a crashed run of the same prefix latched is not this test's.
    let _ = std::fs::remove_dir_all(state_dir().join(scope.prefix()));
    ScopeGuard(scope)
}

/// A test's own folder under the temporary directory, removed when the
/// test ends, also when it fails half-way (set `HYDRACTL_KEEP_SCRATCH` to
/// keep it for a post-mortem).
pub fn scratch_dir(test: &str) -> ScratchDir {
    let dir = std::env::temp_dir().join(format!("hydractl-system-{}-{test}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("scratch dir");
    ScratchDir(dir)
}

pub struct ScratchDir(PathBuf);

impl std::ops::Deref for ScratchDir {
    type Target = Path;
    fn deref(&self) -> &Path {
        &self.0
    }
}

impl AsRef<Path> for ScratchDir {
    fn as_ref(&self) -> &Path {
        &self.0
    }
}

impl Drop for ScratchDir {
    fn drop(&mut self) {
        if std::env::var_os("HYDRACTL_KEEP_SCRATCH").is_none() {
            let _ = std::fs::remove_dir_all(&self.0);
        }
    }
}

/// A `hydractl run` that is stopped when dropped, also when a test fails
/// half-way: SIGTERM, then SIGKILL. Its supervisor and the loop die with it
/// (each process has a parent-death signal). With a log, the run's stderr
/// is printed when the test fails, so that a failure says what the stack
/// said.
pub struct RunGuard(pub Child, pub Option<PathBuf>);

/// Where a run's stderr goes until its test ends: kept and printed only
/// when the test fails.
fn run_log(scope: &RunScope) -> (PathBuf, Stdio) {
    let path = std::env::temp_dir().join(format!("{}run.log", scope.prefix()));
    let file = std::fs::File::create(&path).expect("the run's log");
    (path, Stdio::from(file))
}

impl RunGuard {
    pub fn id(&self) -> u32 {
        self.0.id()
    }
}

impl Drop for RunGuard {
    fn drop(&mut self) {
        if matches!(self.0.try_wait(), Ok(None)) {
            signal(self.0.id(), nix::sys::signal::Signal::SIGTERM);
            let deadline = Instant::now() + Duration::from_secs(5);
            while Instant::now() < deadline && matches!(self.0.try_wait(), Ok(None)) {
                std::thread::sleep(Duration::from_millis(20));
            }
            let _ = self.0.kill();
            let _ = self.0.wait();
        }
        if let Some(log) = self.1.take() {
            if std::thread::panicking() {
                let text = std::fs::read_to_string(&log).unwrap_or_default();
                let lines: Vec<&str> = text.lines().collect();
                eprintln!(
                    "the run's last stderr lines ({}):\n{}",
                    log.display(),
                    lines[lines.len().saturating_sub(60)..].join("\n")
                );
            } else {
                let _ = std::fs::remove_file(&log);
            }
        }
    }
}

/// `hydractl run` with `args` in `scope`.
fn run_command(scope: &RunScope, args: &[&str]) -> Command {
    let mut command = hydractl();
    command
        .arg("run")
        .args(args)
        .env(PREFIX_ENV, scope.prefix())
        .env("RUST_BACKTRACE", "0")
        .stdin(Stdio::null());
    command
}

/// Starts `hydractl run` with `args` in `scope`.
pub fn start_run(scope: &RunScope, args: &[&str]) -> RunGuard {
    let (log, stderr) = run_log(scope);
    RunGuard(
        run_command(scope, args)
            .stderr(stderr)
            .spawn()
            .expect("hydractl run starts"),
        Some(log),
    )
}

/// A `hydractl run` of `duration_s` writing its summary into `dir`, to be
/// ended by [`SummarizedRun::finish`].
pub struct SummarizedRun {
    pub run: RunGuard,
    summary: PathBuf,
}

impl SummarizedRun {
    pub fn start(scope: &RunScope, dir: &Path, duration_s: &str) -> Self {
        let summary = dir.join("summary.json");
        let run = start_run(
            scope,
            &[
                "--duration",
                duration_s,
                "--summary-json",
                summary.to_str().expect("path"),
            ],
        );
        Self { run, summary }
    }

    /// The same, on `config`.
    pub fn with_config(scope: &RunScope, dir: &Path, config: &Path, duration_s: &str) -> Self {
        let summary = dir.join("summary.json");
        let run = start_run(scope, &config_run_args(config, duration_s, &summary));
        Self { run, summary }
    }

    /// SIGTERM, a clean exit; the run's summary.
    pub fn finish(mut self) -> serde_json::Value {
        signal(self.run.id(), nix::sys::signal::Signal::SIGTERM);
        assert!(wait_exit(&mut self.run.0, Duration::from_secs(30)).success());
        read_json(&self.summary)
    }
}

/// `--config CONFIG --duration S --summary-json SUMMARY`, for `hydractl run`.
fn config_run_args<'a>(config: &'a Path, duration_s: &'a str, summary: &'a Path) -> [&'a str; 6] {
    [
        "--config",
        config.to_str().expect("path"),
        "--duration",
        duration_s,
        "--summary-json",
        summary.to_str().expect("path"),
    ]
}

/// `hydractl run --config CONFIG --duration S --summary-json DIR/summary.json`
/// to its end (within a minute more), which must succeed; its summary.
pub fn run_config_for(scope: &RunScope, dir: &Path, config: &Path, duration_s: &str) -> serde_json::Value {
    let summary = dir.join("summary.json");
    let out = run_to_end(
        scope,
        &config_run_args(config, duration_s, &summary),
        Duration::from_secs(60) + Duration::from_secs_f64(duration_s.parse().expect("seconds")),
    );
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    read_json(&summary)
}

/// Runs `hydractl run` to its end, or fails the test after `timeout`.
pub fn run_to_end(scope: &RunScope, args: &[&str], timeout: Duration) -> Output {
    let mut guard = RunGuard(
        run_command(scope, args)
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .expect("hydractl run starts"),
        None,
    );
    wait_exit(&mut guard.0, timeout);
    let child = std::mem::replace(&mut guard.0, Command::new("true").spawn().expect("true"));
    child.wait_with_output().expect("output")
}

/// Asks `probe` every `every` until it answers, for at most `timeout`:
/// its first answer, or `None` when time ran out. A probe that waits on its
/// own (a status read with a timeout) can be asked with `Duration::ZERO`.
pub fn wait_for<T>(timeout: Duration, every: Duration, mut probe: impl FnMut() -> Option<T>) -> Option<T> {
    let deadline = Instant::now() + timeout;
    loop {
        if let Some(answer) = probe() {
            return Some(answer);
        }
        if Instant::now() >= deadline {
            return None;
        }
        std::thread::sleep(every);
    }
}

pub fn wait_exit(child: &mut Child, timeout: Duration) -> std::process::ExitStatus {
    let deadline = Instant::now() + timeout;
    loop {
        if let Some(status) = child.try_wait().expect("wait") {
            return status;
        }
        if Instant::now() > deadline {
            let _ = child.kill();
            panic!("did not exit within {timeout:?}");
        }
        std::thread::sleep(Duration::from_millis(20));
    }
}

pub fn signal(pid: u32, sig: nix::sys::signal::Signal) {
    let _ = nix::sys::signal::kill(nix::unistd::Pid::from_raw(pid as i32), sig);
}

/// A test's own view of a running stack.
pub struct Observer {
    pub status: Reader<SupervisorStatus>,
    pub valve: Reader<ValveSample>,
    pub position: Reader<PositionSample>,
    // Dropped last: the ports above live in this node.
    _bus: Bus,
}

impl Observer {
    pub fn open(scope: &RunScope) -> Self {
        // A run starting at this moment clears its scope's stale files
        // (none of its nodes alive yet) and can take the node's folder
        // from under its creation: iceoryx2 then fails with InternalError.
        // Nothing else opens a node there while a run starts.
        let mut attempts = 0;
        let bus = loop {
            match Bus::open(scope, "observer") {
                Ok(bus) => break bus,
                Err(e) if attempts < 20 => {
                    attempts += 1;
                    eprintln!("observer's node, attempt {attempts}: {e}");
                    std::thread::sleep(Duration::from_millis(100));
                }
                Err(e) => panic!("node: {e:?}"),
            }
        };
        Self {
            status: Reader::open(&bus, service::SUPERVISOR_STATUS, 4).expect("status"),
            valve: Reader::open(&bus, service::VALVE, 256).expect("valve"),
            position: Reader::open(&bus, service::POSITION, 4).expect("position"),
            _bus: bus,
        }
    }

    /// The pid of `name`, once the supervisor reports it running.
    pub fn pid_of(&self, name: &str, timeout: Duration) -> Option<u32> {
        let deadline = Instant::now() + timeout;
        while Instant::now() < deadline {
            std::thread::sleep(Duration::from_millis(20));
            if let Ok(Some(status)) = self.status.latest() {
                let pid = status
                    .processes
                    .iter()
                    .take(status.process_count as usize)
                    .find(|p| name_str(&p.name) == name)
                    .map(|p| p.pid)
                    .filter(|&pid| pid != 0);
                if pid.is_some() {
                    return pid;
                }
            }
        }
        None
    }

    /// Waits until valve samples flow healthy (no fault) for `cycles` in a row.
    pub fn wait_healthy(&self, cycles: usize, timeout: Duration) -> bool {
        self.wait_clean_valve(cycles, timeout, true)
    }

    /// Waits for `count` valve outputs without a fault, `in_a_row` or not.
    fn wait_clean_valve(&self, count: usize, timeout: Duration, in_a_row: bool) -> bool {
        let deadline = Instant::now() + timeout;
        let mut clean = 0;
        while Instant::now() < deadline {
            while let Ok(Some(v)) = self.valve.next() {
                if v.faults == 0 {
                    clean += 1;
                } else if in_a_row {
                    clean = 0;
                }
                if clean >= count {
                    return true;
                }
            }
            std::thread::sleep(Duration::from_millis(2));
        }
        false
    }

    pub fn drain_valve(&self) {
        while let Ok(Some(_)) = self.valve.next() {}
    }

    /// The RMS of reference minus angle over `window`, from the outer
    /// loop's samples, one every 5 ms. An invalid reading (a CAN PDO past
    /// its deadline) has no angle to compare: it is left out.
    pub fn tracking_rms(&self, window: Duration) -> f64 {
        let deadline = Instant::now() + window;
        let (mut sum, mut count) = (0.0, 0usize);
        while Instant::now() < deadline {
            if let Ok(Some(p)) = self.position.latest() {
                let error = p.reference_angle - p.angle;
                if error.is_finite() {
                    sum += error.powi(2);
                    count += 1;
                }
            }
            std::thread::sleep(Duration::from_millis(5));
        }
        // No valid sample in the window: NaN, which no bound passes.
        if count == 0 {
            f64::NAN
        } else {
            (sum / count as f64).sqrt()
        }
    }
}

/// A JSON file a run wrote (its summary).
pub fn read_json(path: &Path) -> serde_json::Value {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    serde_json::from_str(&text).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// `config/sim.toml` changed by `edit`, written to `dir/name`, for a test
/// that needs other settings. The edit must change something.
pub fn config_from_default(dir: &Path, name: &str, edit: impl FnOnce(&str) -> String) -> PathBuf {
    let default = std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("../config/sim.toml"))
        .expect("config/sim.toml");
    let edited = edit(&default);
    assert_ne!(edited, default, "the edit of {name} changed nothing");
    let path = dir.join(name);
    std::fs::write(&path, edited).expect("write the config");
    path
}

/// `hydractl ARGS` against the run in `scope`.
pub fn hydractl_in(scope: &RunScope, args: &[&str]) -> Output {
    hydractl()
        .args(args)
        .env(PREFIX_ENV, scope.prefix())
        .env("RUST_BACKTRACE", "0")
        .output()
        .expect("hydractl runs")
}

/// `hydractl status --json`.
pub fn status(scope: &RunScope) -> serde_json::Value {
    let out = hydractl_in(scope, &["status", "--json"]);
    assert!(
        out.status.success(),
        "{}; {}",
        String::from_utf8_lossy(&out.stderr),
        stall_report(scope)
    );
    serde_json::from_slice(&out.stdout).expect("status json")
}

/// One process's entry in a status.
pub fn process<'a>(status: &'a serde_json::Value, name: &str) -> &'a serde_json::Value {
    status["processes"]
        .as_array()
        .expect("processes")
        .iter()
        .find(|p| p["name"] == name)
        .unwrap_or_else(|| panic!("{name} in {status}"))
}

/// Takes the next waiting sample's sequence number.
type NextSeq = Box<dyn Fn() -> Option<u64>>;

/// The sequence numbers an independent subscriber sees on each pipeline
/// service: what was published, to compare a recording with.
pub struct Witness {
    readers: Vec<(&'static str, NextSeq)>,
    pub seen: BTreeMap<&'static str, BTreeSet<u64>>,
    _bus: Bus,
}

impl Witness {
    pub fn open(scope: &RunScope) -> Self {
        fn reader<T: Recordable>(bus: &Bus, name: &'static str) -> NextSeq {
            let r: Reader<T> = Reader::open(bus, name, 256).expect("reader");
            Box::new(move || {
                r.next()
                    .expect("receive")
                    .and_then(|s| T::KIND.sequence(bytemuck::bytes_of(&s)))
            })
        }
        let bus = Bus::open(scope, "witness").expect("node");
        let readers: Vec<(&'static str, NextSeq)> = vec![
            (
                service::PLANT_READING,
                reader::<PlantReading>(&bus, service::PLANT_READING),
            ),
            (service::SENSOR, reader::<SensorSample>(&bus, service::SENSOR)),
            (service::FRICTION, reader::<FrictionSample>(&bus, service::FRICTION)),
            (service::POSITION, reader::<PositionSample>(&bus, service::POSITION)),
            (service::TORQUE, reader::<TorqueSample>(&bus, service::TORQUE)),
            (service::VALVE, reader::<ValveSample>(&bus, service::VALVE)),
        ];
        Self {
            readers,
            seen: BTreeMap::new(),
            _bus: bus,
        }
    }

    pub fn poll(&mut self) {
        for (name, next) in &self.readers {
            while let Some(seq) = next() {
                self.seen.entry(name).or_default().insert(seq);
            }
        }
    }

    /// A witness on its own thread, polling every 2 ms until
    /// [`WitnessThread::finish`], for a test whose own loop waits.
    pub fn in_background(scope: &RunScope) -> WitnessThread {
        let stop = Arc::new(AtomicBool::new(false));
        let (scope, flag) = (scope.clone(), stop.clone());
        let (opened_tx, opened_rx) = std::sync::mpsc::channel();
        let thread = std::thread::spawn(move || {
            let mut witness = Witness::open(&scope);
            opened_tx.send(()).ok();
            while !flag.load(Ordering::Relaxed) {
                witness.poll();
                std::thread::sleep(Duration::from_millis(2));
            }
            witness.poll();
            witness.seen
        });
        opened_rx.recv().expect("the witness opened its readers");
        WitnessThread {
            stop,
            thread: Some(thread),
        }
    }
}

pub struct WitnessThread {
    stop: Arc<AtomicBool>,
    thread: Option<std::thread::JoinHandle<BTreeMap<&'static str, BTreeSet<u64>>>>,
}

impl WitnessThread {
    /// Stops polling and returns what was seen.
    pub fn finish(mut self) -> BTreeMap<&'static str, BTreeSet<u64>> {
        self.stop.store(true, Ordering::Relaxed);
        self.thread
            .take()
            .map(|t| t.join().expect("the witness thread"))
            .unwrap_or_default()
    }
}

impl Drop for WitnessThread {
    /// A test that fails before `finish` still stops its witness.
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
    }
}

/// A recording's sequence numbers, by topic.
pub fn recorded_sequences(path: &Path) -> BTreeMap<String, BTreeSet<u64>> {
    let mut recorded: BTreeMap<String, BTreeSet<u64>> = BTreeMap::new();
    hydractl_recording::read_messages(path, |m| {
        if let Some(seq) = m.kind.sequence(m.payload) {
            recorded.entry(m.topic.to_owned()).or_default().insert(seq);
        }
        Ok(())
    })
    .unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    recorded
}

/// A `hydractl run` recording to MCAP in `dir` while a witness watches the
/// loop's services, for the fault tests' "nothing lost" check.
pub struct RecordedRun {
    pub run: RunGuard,
    witness: WitnessThread,
    summary: PathBuf,
    recording: PathBuf,
}

impl RecordedRun {
    /// Starts `hydractl run ARGS --summary-json --record` (the witness first,
    /// so it sees the run's first samples).
    pub fn start(scope: &RunScope, dir: &Path, args: &[&str]) -> Self {
        Self::start_with_env(scope, dir, args, &[])
    }

    /// [`RecordedRun::start`] with `env` set for every process of the run.
    pub fn start_with_env(scope: &RunScope, dir: &Path, args: &[&str], env: &[(&str, &str)]) -> Self {
        let (summary, recording) = (dir.join("summary.json"), dir.join("run.mcap"));
        let witness = Witness::in_background(scope);
        let mut all: Vec<&str> = args.to_vec();
        all.extend([
            "--summary-json",
            summary.to_str().expect("path"),
            "--record",
            recording.to_str().expect("path"),
        ]);
        let (log, stderr) = run_log(scope);
        let run = RunGuard(
            run_command(scope, &all)
                .envs(env.iter().copied())
                .stderr(stderr)
                .spawn()
                .expect("hydractl run starts"),
            Some(log),
        );
        Self {
            run,
            witness,
            summary,
            recording,
        }
    }

    /// SIGTERM; a clean exit; the recording holds everything the witness
    /// saw. Returns the run's summary.
    pub fn finish(mut self) -> serde_json::Value {
        signal(self.run.id(), nix::sys::signal::Signal::SIGTERM);
        assert!(wait_exit(&mut self.run.0, Duration::from_secs(30)).success());
        let seen = self.witness.finish();
        let summary = read_json(&self.summary);
        assert_recorded_everything(&seen, &self.recording, &summary);
        summary
    }
}

/// The run's single recording holds every sample the witness saw published
/// on the loop's services, and the recorder dropped nothing. One exception:
/// a publisher killed while it delivers a sample has handed it to some
/// subscribers and not to the others (iceoryx2 delivers to each in turn),
/// so a sample the recording lacks is excused when it was the last its
/// publisher sent (the witness saw no successor) and the run counted a
/// fault for each one excused.
pub(crate) fn assert_recorded_everything(
    seen: &BTreeMap<&'static str, BTreeSet<u64>>,
    recording: &Path,
    summary: &serde_json::Value,
) {
    assert_eq!(summary["recording"]["dropped"], 0, "{}", summary["recording"]);
    assert_eq!(summary["recording"]["files"].as_array().map(Vec::len), Some(1));
    let faults = summary["faults"].as_array().map_or(0, Vec::len);
    let recorded = recorded_sequences(recording);
    let mut excused = Vec::new();
    for topic in PIPELINE_SERVICES {
        let (seen, held) = (&seen[topic], &recorded[topic]);
        let (last_sent, lost): (Vec<u64>, Vec<u64>) =
            seen.difference(held).partition(|&&seq| !seen.contains(&(seq + 1)));
        eprintln!("{topic}: {} published, {} recorded", seen.len(), held.len());
        assert!(lost.is_empty(), "{topic}: published but not recorded: {lost:?}");
        excused.extend(last_sent.into_iter().map(|seq| (topic, seq)));
    }
    assert!(
        excused.len() <= faults,
        "published but not recorded, each the last its publisher sent, more than the run's {faults} fault(s): {excused:?}"
    );
}

/// Reads a recording with the Python `mcap` package and its ROS 2 decoder
/// (`tests/python`). `None` when they are not installed and not required
/// (`HYDRACTL_REQUIRE_PYTHON_MCAP=1`, as `.ci/run` sets).
pub fn python_view(args: &[&str], path: &Path) -> Option<serde_json::Value> {
    let python = std::env::var("HYDRACTL_PYTHON").unwrap_or_else(|_| "python3".into());
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("python/check_recording.py");
    independent_view(
        "the Python mcap reader (install mcap and mcap-ros2-support, as .ci/run does)",
        "HYDRACTL_REQUIRE_PYTHON_MCAP",
        Command::new(python).arg(script).args(args).arg(path),
    )
}

/// Reads a recording with the libraries Foxglove itself uses, `@mcap/core`
/// and `@foxglove/rosmsg2-serialization` (`tests/js`). `None` when they are
/// not installed and not required (`HYDRACTL_REQUIRE_JS_MCAP=1`).
pub fn foxglove_view(path: &Path) -> Option<serde_json::Value> {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("js/check_recording.mjs");
    independent_view(
        "Foxglove's readers (`npm ci` in tests/js, as .ci/run does)",
        "HYDRACTL_REQUIRE_JS_MCAP",
        Command::new("node").arg(script).arg(path),
    )
}

/// Runs an outside reader. Only a reader that is not installed (no
/// interpreter, or its library missing) may skip, and not when
/// `required_by` is set; a reader that ran and rejected the recording
/// fails the test.
fn independent_view(what: &str, required_by: &str, command: &mut Command) -> Option<serde_json::Value> {
    let required = std::env::var(required_by).is_ok_and(|v| v == "1");
    let why = match command.output() {
        Ok(out) if out.status.success() => {
            return Some(serde_json::from_slice(&out.stdout).expect("the reader's json"));
        }
        Ok(out) => {
            let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
            let not_installed = [
                "ModuleNotFoundError",
                "ERR_MODULE_NOT_FOUND",
                "Cannot find module",
                "Cannot find package",
            ]
            .iter()
            .any(|sign| stderr.contains(sign));
            assert!(not_installed, "{what} rejected the recording: {stderr}");
            stderr
        }
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => e.to_string(),
        Err(e) => panic!("{what} could not be started: {e}"),
    };
    assert!(!required, "{what} is not installed: {why}");
    eprintln!("SKIPPED the check by {what}, not installed: {why}");
    None
}
