//! `hydractl run`: starts the supervisor (which starts the loop), watches
//! the loop's samples, shows a live status, and writes the run's summary.

use std::collections::BTreeMap;
use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use anyhow::{bail, Context, Result};
use hydractl_bus::{quiet_ipc_logging, run_loop, Bus, Flow, LoopExit, Reader, RunScope, PREFIX_ENV};
use hydractl_config::Config;
use hydractl_samples::{
    code, name_str, service, FrictionSample, PlantReading, PositionSample, SensorSample, SupervisorEvent,
    SupervisorStatus, ValveSample,
};
use nix::sys::signal::{kill, Signal};
use nix::unistd::Pid;
use serde::Serialize;

mod monitor;
mod valve_faults;

use monitor::{merge_status, LatencyHistogram, LiveLine, Tracking};

#[derive(clap::Args)]
pub struct RunArgs {
    /// Configuration file [default: the built-in config/sim.toml].
    #[arg(long)]
    config: Option<PathBuf>,
    /// Seconds to run, counted from the loop's first cycle (0: start the
    /// whole stack, run one cycle, stop); without it, until Ctrl-C or SIGTERM.
    #[arg(long)]
    duration: Option<f64>,
    /// Write the run's summary as JSON.
    #[arg(long)]
    summary_json: Option<PathBuf>,
    /// Record every sample to this MCAP file.
    #[arg(long)]
    record: Option<PathBuf>,
    #[command(flatten)]
    split: hydractl_processes::SplitArgs,
}

#[derive(Serialize)]
struct StageLatency {
    stage: &'static str,
    from_reading: LatencySummary,
}

/// The chain's stages, in order, as `latency_by_stage_us` names them.
const STAGES: [&str; 5] = ["sensor", "friction", "position", "torque", "valve"];
const VALVE_STAGE: usize = STAGES.len() - 1;

#[derive(Serialize)]
struct LatencySummary {
    p50: f64,
    p99: f64,
    p999: f64,
    max: f64,
}

#[derive(Serialize, Clone, Default)]
struct ProcessSummary {
    name: String,
    pids: Vec<u32>,
    restarts: u32,
    /// A loop process: page faults after it entered its loop, over all its
    /// pids (the goal is 0: its memory locked and touched before). Null
    /// for a process with no loop, or none that entered it.
    page_faults_after_start: Option<u64>,
    /// A loop process: whether every one of its pids locked its memory.
    memory_locked: Option<bool>,
    /// The newest count of each pid.
    #[serde(skip)]
    faults_by_pid: Vec<(u32, u64, bool)>,
}

#[derive(Serialize)]
struct RunSummary {
    duration_s: f64,
    cycles: u64,
    deadline_misses: u64,
    /// Sensor reading to valve command, from the samples' own timestamps.
    latency_us: LatencySummary,
    /// From the sensor reading to each stage's output, stage by stage along
    /// the chain: where the time goes.
    latency_by_stage_us: Vec<StageLatency>,
    max_abs_tracking_error_rad: f64,
    rms_tracking_error_rad: f64,
    /// Valve samples published in neutral with a fault flag.
    valve_fault_cycles: u64,
    /// The machine's valve's latched faults (CAN), each with its reset.
    valve_faults: Vec<valve_faults::ValveFaultSummary>,
    processes: Vec<ProcessSummary>,
    /// Processes that crashed or hung, and how the stack recovered.
    faults: Vec<FaultSummary>,
    /// Processes that are none of the run's and published on one of its
    /// services ([SAFETY.md](../../SAFETY.md), H10).
    strangers: Vec<StrangerSummary>,
    /// Controller swaps while the run ran, as the supervisor judged them.
    swaps: Vec<SwapSummary>,
    /// Swaps asked for that did not happen: the running controller stayed.
    swap_failures: Vec<SwapSummary>,
    /// The plant the loop drove at the end: `machine` or `simulation`.
    plant: &'static str,
    /// Each change of plant: the machine lost, or asked for.
    plant_switches: Vec<PlantSwitchSummary>,
    /// What the recording holds, read back from its file(s) after the run.
    #[serde(skip_serializing_if = "Option::is_none")]
    recording: Option<RecordingReport>,
    /// The machine's CAN bus as a listener on it saw it.
    #[serde(skip_serializing_if = "Option::is_none")]
    can: Option<CanSummary>,
    /// The shadow model's last window, when `[shadow] model` is set.
    #[serde(skip_serializing_if = "Option::is_none")]
    shadow: Option<ShadowSummary>,
    /// Each drift of the machine from its model the shadow detected, with
    /// the effect its diagnosis named (none: not named, or not yet).
    model_drift: Vec<DriftSummary>,
    #[serde(skip)]
    recorder: RecorderView,
}

#[derive(Serialize)]
struct ShadowSummary {
    model: String,
    /// Windows compared.
    windows: u64,
    /// The last window's fit per output, percent (`theta`, `p_a`, `p_b`).
    fit_percent: BTreeMap<&'static str, f64>,
    /// The last window's residual RMS: pressures in Pa, angle in rad.
    residual_pressures_pa: Option<f64>,
    residual_angle_rad: Option<f64>,
    /// Times the shadow's rows started afresh (a reading it lost, a
    /// handover, a flagged reading).
    row_gaps: u64,
}

#[derive(Serialize)]
struct DriftSummary {
    part: String,
    regime: String,
    /// The machine's time at detection, s from the loop's first reading.
    detected_after_s: f64,
    /// How much the part's residual grew, as a ratio of RMS.
    rms_ratio: f64,
    /// The effect the diagnosis named, and its fitted parameters.
    effect: Option<String>,
    params: BTreeMap<String, f64>,
    /// `named`, `not named` (no effect of the catalog explains it) or
    /// `diagnosing` (the run ended first).
    outcome: &'static str,
}

impl DriftSummary {
    fn of(d: &hydractl_samples::ModelDrift) -> Self {
        use hydractl_samples::drift;
        let effect = Some(name_str(&d.effect).to_owned()).filter(|e| !e.is_empty());
        let keys: Vec<&str> = effect
            .as_deref()
            .and_then(|e| hydractl_plant::EffectKind::from_name(e).ok())
            .map(|k| k.params().iter().map(|p| p.key).collect())
            .unwrap_or_default();
        Self {
            part: name_str(&d.part).to_owned(),
            regime: name_str(&d.regime).to_owned(),
            detected_after_s: d.detected_after_s,
            rms_ratio: d.rms_ratio,
            effect,
            params: keys
                .iter()
                .zip(d.params)
                .filter(|(_, v)| v.is_finite())
                .map(|(k, v)| ((*k).to_owned(), v))
                .collect(),
            outcome: match d.stage {
                drift::NAMED => "named",
                drift::UNNAMED => "not named",
                _ => "diagnosing",
            },
        }
    }
}

#[derive(Serialize)]
struct CanSummary {
    /// The interface (`vcan0` on the virtual bus, `can0` on the vehicle).
    bus: String,
    bitrate: u32,
    /// Bus time of every frame, stuffing counted bit for bit, over the run.
    load_percent: f64,
    /// Frames per SYNC.
    frames_per_period: f64,
    /// A sensor value the machine did not have at `[can] pdo_deadline_us`
    /// after its SYNC: the reading went out with it missing (invalid).
    late_pdos: u64,
    /// A period's TPDO that never came before the next SYNC.
    lost_frames: u64,
    /// A period's TPDO of another length than its mapping's (refused).
    malformed_pdos: u64,
    error_frames: u64,
    emcy: u64,
    /// The virtual bus's wire, by its own counters (null on SocketCAN):
    /// frames that crossed it and frames it lost (a full transmit queue,
    /// or handed over while bus-off).
    wire: Option<WireSummary>,
}

#[derive(Serialize)]
struct WireSummary {
    delivered: u64,
    lost: u64,
    error_frames: u64,
}

#[derive(Serialize)]
struct RecordingReport {
    files: Vec<String>,
    messages: u64,
    channels: usize,
    /// Samples the recorder lost by falling behind (its last status).
    dropped: u64,
    /// Sequence numbers the publishers skipped themselves (a stage that took
    /// the newest reading): in the data, not lost by the recording.
    gaps: u64,
    /// Everything the recorder received is in the files, and it never
    /// stopped: false makes the run exit 3.
    complete: bool,
    /// What never reached a file: the disk was full.
    not_recorded: Option<NotRecorded>,
    /// Times the disk was full.
    disk_full: u32,
    /// Oldest parts deleted to keep within `keep_mb` (a ring, by design).
    deleted_files: u32,
    /// Times the recorder itself was restarted: what it missed in between
    /// is not counted.
    recorder_restarts: u32,
}

#[derive(Serialize, Clone, Copy, PartialEq)]
struct NotRecorded {
    /// Samples received and not recorded.
    samples: u64,
    /// The first of them, in seconds from the run's first reading.
    from_s: f64,
}

#[derive(Serialize)]
struct PlantSwitchSummary {
    from: String,
    to: String,
    /// `machine lost` or `asked`.
    cause: &'static str,
    /// The first reading from the new plant.
    at_seq: u64,
    /// For a lost machine: from its last reading to the switch.
    detected_after_ms: f64,
}

impl FaultSummary {
    /// One line for the terminal: what happened, and how the loop came through it.
    fn says(&self) -> String {
        let valve = self
            .valve_safe_after_periods
            .map_or("the valve had nothing stale".to_owned(), |p| {
                format!("valve safe after {p} periods")
            });
        let back = match (self.restarted_after_ms, &self.restarted_as) {
            (Some(ms), Some(variant)) => format!("restarted as {variant} after {ms:.0} ms"),
            (Some(ms), None) => format!("restarted after {ms:.0} ms"),
            (None, _) => "left down".to_owned(),
        };
        format!(
            "{} (pid {}): {} after reading {}, found after {:.0} ms; {valve}; {back}",
            self.process, self.pid, self.kind, self.last_seq, self.detected_after_ms
        )
    }
}

#[derive(Serialize)]
struct StrangerSummary {
    pid: u32,
    /// The service it published on, without the `hydractl/` in front.
    service: String,
    /// The loop's newest reading when it was found.
    at_seq: u64,
}

#[derive(Serialize)]
struct FaultSummary {
    process: String,
    /// `crash` (it exited), `hang` (no output while its input flowed),
    /// `misbehaving` (the valve rejected its commands as garbage, reading
    /// after reading), `limit_cycle` (the valve found its commands
    /// limit-cycling and held neutral) or `spin` (it took more than its
    /// share of the loop's CPU, starving the processes beside it).
    kind: &'static str,
    pid: u32,
    /// The last reading it answered.
    last_seq: u64,
    /// From its last output to the supervisor seeing the fault.
    detected_after_ms: f64,
    /// Readings from the last one it answered to the first with the valve
    /// made safe; null when the valve never had to be (it had nothing stale).
    valve_safe_after_periods: Option<u64>,
    /// From the detection to the new process's first output; null when
    /// its restart rule left it down.
    restarted_after_ms: Option<f64>,
    /// A misbehaving controller: the variant it was restarted into.
    #[serde(skip_serializing_if = "Option::is_none")]
    restarted_as: Option<String>,
    /// The tracking error's largest magnitude over the second after the
    /// fault's account arrived (its process back), rad: whether the
    /// restart shook the load. Null when the run ended before that second.
    tracking_error_max_after_rad: Option<f64>,
}

#[derive(Serialize)]
struct SwapSummary {
    stage: String,
    from: String,
    to: String,
    /// The first sensor reading the new controller answered.
    at_seq: u64,
    missed_cycles: u64,
    /// The valve command's largest step from the switch through its
    /// transient (5 readings), as a fraction of its range.
    command_step: f64,
    /// The loop's own largest steps: in the second before the switch, and
    /// in the second after its transient.
    loop_step_before: f64,
    loop_step_after: f64,
}

pub fn run(mut args: RunArgs) -> Result<()> {
    if let Some(d) = args.duration {
        if !(d.is_finite() && d >= 0.0) {
            bail!("--duration must be a finite number of seconds, got {d}");
        }
    }
    // A run's results must have somewhere to go before the run starts.
    if let Some(path) = &args.summary_json {
        check_writable(path, "--summary-json")?;
    }
    let config = Config::load_or_default(args.config.as_deref())?;
    if let Some(can) = &config.can {
        if can.transport == hydractl_can::profile::Transport::Socketcan {
            // Said here, once, before anything starts: a process that could
            // not open it would only be restarted again and again.
            hydractl_bus::can::SocketCanPort::open(&can.interface, &[])
                .with_context(|| format!("the machine's CAN bus ([can] in {})", config_name(&args.config)))?;
        }
    }
    // The flags first, then the config's [recording].
    let recording = &config.recording;
    let from_config = args.record.is_none() && recording.out.is_some();
    // Each run of the config's recording its own file, named by its start,
    // in one ring with the earlier runs'.
    let mut ring = None;
    args.record = args.record.take().or_else(|| {
        let out = recording.out.as_ref()?;
        let stem = out.file_stem()?.to_string_lossy().into_owned();
        let started = humantime::format_rfc3339_seconds(std::time::SystemTime::now())
            .to_string()
            .replace(':', "");
        ring = Some(stem.clone());
        Some(out.with_file_name(format!("{stem}-{started}.mcap")))
    });
    args.split.split_size_mb = args.split.split_size_mb.or(recording.split_size_mb);
    args.split.split_duration_s = args.split.split_duration_s.or(recording.split_duration_s);
    args.split.keep_mb = args.split.keep_mb.or(recording.keep_mb);
    if let Some(path) = &args.record {
        if from_config {
            if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty() && !d.exists()) {
                std::fs::create_dir_all(dir).with_context(|| {
                    format!(
                        "[recording] out in {}: creating {}",
                        config_name(&args.config),
                        dir.display()
                    )
                })?;
            }
        }
        check_writable(path, if from_config { "[recording] out" } else { "--record" })?;
        if args.split.keep_mb.is_some() && !args.split.splits() {
            bail!("keep_mb needs a split to delete: --split-size-mb or --split-duration-s (or [recording] split_size_mb, split_duration_s)");
        }
    }
    // A model the shadow cannot use is said now, not by a process that
    // crash-loops under the supervisor.
    if let Some(path) = &config.shadow.model {
        let model = hydractl_ident::greybox::Model::load(path).context("[shadow] model")?;
        hydractl_ident::greybox::Shadow::new(model, Default::default())
            .with_context(|| format!("[shadow] model {}", path.display()))?;
    }
    if let Err(e) = hydractl_bus::placement::keep_off_loop_cpu(config.timing.loop_cpu) {
        tracing::warn!("{e}");
    }
    quiet_ipc_logging();
    let scope = RunScope::from_env()?;
    // Over a crashed run's leftovers: clean its dead nodes, and its files if
    // nothing of it is alive.
    scope.remove_dead_nodes()?;
    if scope.live_node_names()?.iter().any(|name| name == "supervisor") {
        bail!(
            "a run with prefix `{}` is already alive; stop it or set {PREFIX_ENV} to another prefix",
            scope.prefix()
        );
    }
    scope.clean_stale()?;
    let dir = hydractl_bus::process_dir()?;
    // The virtual bus and the simulated ECUs are the machine here: they are
    // there before the stack and outlive it, so that the valve's last
    // frames reach the valve.
    let machine = match &config.can {
        Some(can) if can.transport == hydractl_can::profile::Transport::Virtual => {
            Some(VirtualMachine::start(&scope, &dir, args.config.as_deref())?)
        }
        _ => None,
    };
    let taps = Taps::open(&scope)?;
    // Read apart from the taps: its last word comes as the stack stops.
    let recorder: Reader<hydractl_samples::RecorderStatus> = Reader::open(&taps.bus, service::RECORDER_STATUS, 16)?;
    let mut command = Command::new(dir.join("supervisor"));
    if let Some(config) = &args.config {
        command.arg("--config").arg(config);
    }
    if let Some(out) = &args.record {
        command.args(args.split.recorder_args(out)?);
        if let Some(ring) = &ring {
            command.args(["--ring", ring]);
        }
    }
    // Its own process group: a terminal's Ctrl-C reaches only us, and we
    // stop the supervisor, which stops the loop in order.
    use std::os::unix::process::CommandExt;
    let mut supervisor = command
        .env(PREFIX_ENV, scope.prefix())
        .stdin(Stdio::null())
        .process_group(0)
        .spawn()
        .with_context(|| format!("starting {}", dir.join("supervisor").display()))?;
    let supervisor_pid = supervisor.id();
    let outcome = watch(taps, &recorder, &args, &config, supervisor_pid);
    // The supervisor stops the loop, then lets the recorder finish its file.
    stop_child(&mut supervisor, "the supervisor", Duration::from_secs(15))?;
    let mut summary = outcome?;
    if let Some(out) = &args.record {
        // Its last status, sent as it finished: what it did not record.
        while let Some(status) = recorder.next()? {
            summary.recorder.last = Some(status);
        }
        summary.recorder.restarts = summary
            .processes
            .iter()
            .find(|p| p.name == "recorder")
            .map_or(0, |p| p.restarts);
        summary.recording = Some(recording_report(out, summary.recorder)?);
    }
    // Our last port closed and the machine stopped, nothing of the run is
    // alive: what the supervisor could not remove while we still read is
    // removed now. Stopped after this, the machine's processes left their
    // node counter (`….global_mgmt`) and the run's folder behind.
    drop(recorder);
    drop(machine);
    scope.clean_stale()?;
    if let Some(path) = &args.summary_json {
        std::fs::write(path, serde_json::to_string_pretty(&summary)? + "\n")
            .with_context(|| format!("cannot write {}", path.display()))?;
    }
    if let Some(r) = &summary.recording {
        eprintln!(
            "recorded {} messages on {} channels, {} dropped by the recorder, {} skipped by publishers, to {}{}",
            r.messages,
            r.channels,
            r.dropped,
            r.gaps,
            r.files.join(", "),
            if r.deleted_files > 0 {
                format!(" ({} oldest parts deleted to keep within keep_mb)", r.deleted_files)
            } else {
                String::new()
            }
        );
    }
    if let Some(c) = &summary.can {
        eprintln!(
            "CAN {} at {} bit/s: load {:.1} %, {:.2} frames a period, {} late PDOs, {} lost, {} error frames, {} EMCY{}",
            c.bus,
            c.bitrate,
            c.load_percent,
            c.frames_per_period,
            c.late_pdos,
            c.lost_frames,
            c.error_frames,
            c.emcy,
            c.wire
                .as_ref()
                .map_or(String::new(), |w| format!("; the wire: {} delivered, {} lost", w.delivered, w.lost))
        );
    }
    for f in &summary.valve_faults {
        eprintln!(
            "VALVE FAULT {}{} at {:.1} s: {}; {}",
            hydractl_can::valve::fault_code_name(f.code),
            if f.latched_before_run {
                " (latched before this run)"
            } else {
                ""
            },
            f.at_s,
            f.meaning,
            match f.reset_at_s {
                Some(t) => format!("reset at {t:.1} s"),
                None => "STILL LATCHED: the valve stays neutral until `hydractl valve reset`".to_owned(),
            }
        );
    }
    for switch in &summary.plant_switches {
        eprintln!(
            "plant: {} → {} ({}) from reading {}",
            switch.from, switch.to, switch.cause, switch.at_seq
        );
    }
    if summary.plant == "simulation" && !summary.plant_switches.is_empty() {
        tracing::warn!("the run ended on the SIMULATED plant, not the machine");
    }
    crate::emit(&format!(
        "{} cycles, {} deadline misses, latency p50 {} µs p99 {} µs p99.9 {} µs max {:.0} µs, tracking error rms {:.4} rad max {:.4} rad, {} restart(s)\n",
        summary.cycles,
        summary.deadline_misses,
        summary.latency_us.p50,
        summary.latency_us.p99,
        summary.latency_us.p999,
        summary.latency_us.max,
        summary.rms_tracking_error_rad,
        summary.max_abs_tracking_error_rad,
        summary.processes.iter().map(|p| p.restarts).sum::<u32>()
    ))?;
    match &summary.recording {
        Some(r) if !r.complete => Err(RecordingIncomplete(r.what_is_missing()).into()),
        _ => Ok(()),
    }
}

/// The run went through, but its recording misses something: `hydractl
/// run` exits 3, after the summary that says what.
#[derive(Debug)]
pub struct RecordingIncomplete(String);

impl std::fmt::Display for RecordingIncomplete {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "the recording is INCOMPLETE: {}", self.0)
    }
}

impl std::error::Error for RecordingIncomplete {}

impl RecordingReport {
    fn what_is_missing(&self) -> String {
        let mut missing = Vec::new();
        if let Some(n) = self.not_recorded {
            missing.push(format!(
                "{} samples from {:.3} s into the run on were not recorded (the disk was full {} time{})",
                n.samples,
                n.from_s,
                self.disk_full,
                if self.disk_full == 1 { "" } else { "s" }
            ));
        }
        if self.recorder_restarts > 0 {
            missing.push(format!(
                "the recorder was restarted {} time{}, and what it missed meanwhile is not counted",
                self.recorder_restarts,
                if self.recorder_restarts == 1 { "" } else { "s" }
            ));
        }
        if missing.is_empty() {
            missing.push("a file of it cannot be read, or the recorder never said what it wrote".to_owned());
        }
        missing.join("; ")
    }
}

/// What `run` reads of the loop, opened before the stack starts: each
/// stage connects to these readers as it opens its output, not on its loop.
struct Taps {
    bus: Bus,
    valve: Reader<ValveSample>,
    position: Reader<PositionSample>,
    plant: Reader<PlantReading>,
    status: Reader<SupervisorStatus>,
    sensor: Reader<SensorSample>,
    friction: Reader<FrictionSample>,
    torque: Reader<hydractl_samples::TorqueSample>,
    events: Reader<SupervisorEvent>,
    shadow: Reader<hydractl_samples::ShadowSample>,
    drift: Reader<hydractl_samples::ModelDrift>,
    device: Reader<hydractl_samples::ValveDevice>,
}

impl Taps {
    fn open(scope: &RunScope) -> Result<Self> {
        let bus = Bus::open(scope, "monitor")?;
        Ok(Self {
            valve: Reader::open(&bus, service::VALVE, 256)?,
            position: Reader::open(&bus, service::POSITION, 256)?,
            plant: Reader::open(&bus, service::PLANT_READING, 4)?,
            status: Reader::open(&bus, service::SUPERVISOR_STATUS, 4)?,
            sensor: Reader::open(&bus, service::SENSOR, 256)?,
            friction: Reader::open(&bus, service::FRICTION, 256)?,
            torque: Reader::open(&bus, service::TORQUE, 256)?,
            events: Reader::open(&bus, service::SUPERVISOR_EVENTS, 64)?,
            shadow: Reader::open(&bus, service::SHADOW, 16)?,
            drift: Reader::open(&bus, service::SHADOW_DRIFT, 16)?,
            device: Reader::open(&bus, service::VALVE_DEVICE, 16)?,
            bus,
        })
    }
}

/// One figure for the shadow's fit: its worst output's.
/// The window's fit per output, percent, where measured.
pub(crate) fn fit_percent(s: &hydractl_samples::ShadowSample) -> BTreeMap<&'static str, f64> {
    [("theta", s.fit_theta), ("p_a", s.fit_p_a), ("p_b", s.fit_p_b)]
        .into_iter()
        .filter(|(_, v)| v.is_finite())
        .collect()
}

pub(crate) fn shadow_fit(s: &hydractl_samples::ShadowSample) -> f64 {
    [s.fit_theta, s.fit_p_a, s.fit_p_b]
        .into_iter()
        .filter(|v| v.is_finite())
        .fold(f64::NAN, f64::min)
}

fn watch(
    taps: Taps,
    recorder: &Reader<hydractl_samples::RecorderStatus>,
    args: &RunArgs,
    config: &Config,
    supervisor_pid: u32,
) -> Result<RunSummary> {
    let Taps {
        bus,
        valve,
        position,
        plant,
        status,
        sensor,
        friction,
        torque,
        events,
        shadow,
        drift,
        device,
    } = taps;
    let mut valve_faults = valve_faults::ValveFaults::default();
    let started = Instant::now();
    // The duration runs from the loop's first cycle: a run is never stopped
    // while its processes are still starting (their start-up is not made to
    // be interrupted), however short it is asked to be.
    let duration = args.duration.map(|d| Duration::from_secs_f64(d.max(0.0)));
    let mut end: Option<Instant> = None;
    let live = std::io::stderr().is_terminal();
    eprintln!(
        "{}",
        LiveLine::header(config.machine.is_some(), config.shadow.model.is_some())
    );
    // From the reading to each stage's output; the valve's is the
    // sensor-to-valve latency.
    let mut by_stage: [LatencyHistogram; STAGES.len()] = std::array::from_fn(|_| LatencyHistogram::new());
    let mut tracking = Tracking::new(config.timing.control_rate_hz.round() as usize);
    let machine_expected = config.machine.is_some();
    let mut cycles = 0u64;
    let mut faults = 0u64;
    let mut late = 0u64;
    let mut last_valve_seq: Option<u64> = None;
    let mut processes: Vec<ProcessSummary> = vec![ProcessSummary {
        name: "supervisor".into(),
        pids: vec![supervisor_pid],
        ..ProcessSummary::default()
    }];
    let mut last_print = Instant::now();
    let mut cycles_at_last_print = 0u64;
    let (mut swaps, mut swap_failures) = (Vec::new(), Vec::new());
    let mut faults_seen: Vec<FaultSummary> = Vec::new();
    let mut strangers = Vec::new();
    // Faults whose second after is still being watched: (index, errors seen then).
    let mut after_fault: Vec<(usize, u64)> = Vec::new();
    let per_second = config.timing.control_rate_hz.round() as u64;
    let mut plant_switches = Vec::new();
    let mut on_simulation = true;
    // Each plant counts its own late commands.
    let mut late_by_source = [0u64; 2];
    let mut failure = None;
    let mut recorder_view = RecorderView::default();
    let mut late_pdos = 0u64;
    let mut shadow_last: Option<hydractl_samples::ShadowSample> = None;
    let mut shadow_windows = 0u64;
    // By the reading it was detected at: a named drift replaces its alarm.
    let mut drifts: Vec<(u64, DriftSummary)> = Vec::new();
    let mut can_watch = match &config.can {
        Some(can) => {
            let profile = can.resolve()?;
            let port = hydractl_bus::can::open_monitor(&bus, &profile)?;
            // Every reading, for the machine's PDOs that were not there in time.
            let readings: Reader<PlantReading> = Reader::open(&bus, service::PLANT_READING, 256)?;
            let wire: Reader<hydractl_samples::WireStatus> =
                Reader::open(&bus, &service::can_wire(&profile.interface), 4)?;
            Some((
                port,
                hydractl_can::stats::BusStats::new(&profile),
                profile,
                readings,
                wire,
                None,
            ))
        }
        None => None,
    };
    let exit = run_loop(&[], Some(Duration::from_millis(10)), &bus, |_| {
        let mut step = || -> Result<Flow> {
            if let Some((port, stats, _, machine_readings, wire, wire_last)) = &mut can_watch {
                while let Some(received) = port.receive()? {
                    stats.on_frame(&received.frame, received.time_ns);
                }
                while let Some(w) = wire.next()? {
                    *wire_last = Some(w);
                }
                while let Some(r) = machine_readings.next()? {
                    if r.source == hydractl_samples::source::MACHINE {
                        late_pdos += [r.angle, r.p_a, r.p_b].iter().filter(|v| v.is_nan()).count() as u64;
                    }
                }
            }
            while let Some(status) = recorder.next()? {
                recorder_view.last = Some(status);
            }
            while let Some(v) = valve.next()? {
                if recorder_view.first_reading_ns == 0 {
                    recorder_view.first_reading_ns = v.sensor_time_ns;
                }
                // The valve process starting or stopping answers no reading.
                if v.faults & hydractl_samples::fault::OFF != 0 {
                    continue;
                }
                // One command per sensor reading; a neutral published on a
                // later reading while the chain is broken counts as a cycle too.
                if last_valve_seq.is_none_or(|last| v.sensor_seq > last) {
                    cycles += 1;
                    last_valve_seq = Some(v.sensor_seq);
                    // Only a sample derived from a reading has a latency.
                    if v.sensor_time_ns != 0 {
                        by_stage[VALVE_STAGE].record_between(v.sensor_time_ns, v.stage_time_ns);
                    }
                }
                if v.faults != 0 {
                    faults += 1;
                }
            }
            while let Some(x) = sensor.next()? {
                by_stage[0].record_between(x.sensor_time_ns, x.stage_time_ns);
            }
            while let Some(x) = friction.next()? {
                by_stage[1].record_between(x.sensor_time_ns, x.stage_time_ns);
            }
            while let Some(p) = position.next()? {
                by_stage[2].record_between(p.sensor_time_ns, p.stage_time_ns);
                let e = p.reference_angle - p.angle;
                // An invalid reading (a PDO that did not come) has no angle:
                // the valve was neutral for it, and the next one counts.
                if e.is_finite() {
                    tracking.push(e);
                }
                if after_fault
                    .first()
                    .is_some_and(|&(_, at)| tracking.count() >= at + per_second)
                {
                    let (i, _) = after_fault.remove(0);
                    faults_seen[i].tracking_error_max_after_rad = Some(tracking.last_second().max_abs);
                }
            }
            if let Some(p) = plant.latest()? {
                late_by_source[usize::from(p.source == hydractl_samples::source::MACHINE)] = p.late_commands;
                late = late_by_source.iter().sum();
            }
            while let Some(t) = torque.next()? {
                by_stage[3].record_between(t.sensor_time_ns, t.stage_time_ns);
            }
            if let Some(s) = status.latest()? {
                merge_status(&mut processes, &s);
                on_simulation = s.plant_is_simulation != 0;
            }
            while let Some(e) = events.next()? {
                let swap = SwapSummary {
                    stage: name_str(&e.process).to_owned(),
                    from: name_str(&e.from).to_owned(),
                    to: name_str(&e.to).to_owned(),
                    at_seq: e.sensor_seq,
                    missed_cycles: e.missed_cycles,
                    command_step: e.command_step,
                    loop_step_before: e.loop_step_before,
                    loop_step_after: e.loop_step_after,
                };
                match e.kind {
                    code::EVENT_FALLBACK | code::EVENT_PLANT_SWITCH => {
                        let lost = e.kind == code::EVENT_FALLBACK;
                        if lost {
                            above_live_line(live);
                            tracing::warn!(
                                event = "fallback",
                                seq = e.sensor_seq,
                                "the machine is lost: the loop now runs on the SIMULATED plant from reading {}",
                                e.sensor_seq
                            );
                        }
                        plant_switches.push(PlantSwitchSummary {
                            from: swap.from,
                            to: swap.to,
                            cause: if lost { "machine lost" } else { "asked" },
                            at_seq: e.sensor_seq,
                            detected_after_ms: e.detected_after_ns as f64 * 1e-6,
                        });
                    }
                    code::EVENT_STRANGER => {
                        let stranger = StrangerSummary {
                            pid: e.pid,
                            service: name_str(&e.process).to_owned(),
                            at_seq: e.sensor_seq,
                        };
                        above_live_line(live);
                        tracing::warn!(
                            event = "stranger",
                            seq = stranger.at_seq,
                            "a stranger, process {}, publishes on the run's {} (at reading {})",
                            stranger.pid,
                            stranger.service,
                            stranger.at_seq
                        );
                        strangers.push(stranger);
                    }
                    code::EVENT_SWAP => {
                        above_live_line(live);
                        tracing::info!(
                            event = "swap",
                            stage = swap.stage.as_str(),
                            seq = swap.at_seq,
                            "{} now runs {} (was {}) from reading {}: {} missed cycles, command step {:.2} % of its range",
                            swap.stage,
                            swap.to,
                            swap.from,
                            swap.at_seq,
                            swap.missed_cycles,
                            swap.command_step * 100.0
                        );
                        swaps.push(swap);
                    }
                    code::EVENT_SWAP_FAILED => {
                        above_live_line(live);
                        tracing::warn!(
                            event = "swap_failed",
                            stage = swap.stage.as_str(),
                            "{} did not change to {}: {} stays in charge",
                            swap.stage,
                            swap.to,
                            swap.from
                        );
                        swap_failures.push(swap);
                    }
                    code::EVENT_CRASH
                    | code::EVENT_HANG
                    | code::EVENT_MISBEHAVING
                    | code::EVENT_LIMIT_CYCLE
                    | code::EVENT_SPIN => {
                        let fault = FaultSummary {
                            process: name_str(&e.process).to_owned(),
                            kind: match e.kind {
                                code::EVENT_CRASH => "crash",
                                code::EVENT_HANG => "hang",
                                code::EVENT_LIMIT_CYCLE => "limit_cycle",
                                code::EVENT_SPIN => "spin",
                                _ => "misbehaving",
                            },
                            pid: e.pid,
                            last_seq: e.sensor_seq,
                            detected_after_ms: e.detected_after_ns as f64 * 1e-6,
                            valve_safe_after_periods: (e.valve_safe_after_periods != u64::MAX)
                                .then_some(e.valve_safe_after_periods),
                            restarted_after_ms: (e.restarted_after_ns != u64::MAX)
                                .then_some(e.restarted_after_ns as f64 * 1e-6),
                            restarted_as: Some(name_str(&e.to).to_owned()).filter(|v| !v.is_empty()),
                            tracking_error_max_after_rad: None,
                        };
                        after_fault.push((faults_seen.len(), tracking.count()));
                        // Said as it happens, above the live line.
                        above_live_line(live);
                        tracing::warn!(
                            event = fault.kind,
                            child = fault.process.as_str(),
                            child_pid = fault.pid,
                            seq = fault.last_seq,
                            "{}",
                            fault.says()
                        );
                        faults_seen.push(fault);
                    }
                    _ => {}
                }
            }
            while let Some(d) = device.next()? {
                valve_faults.on_device(&d, started.elapsed().as_secs_f64());
            }
            while let Some(s) = shadow.next()? {
                shadow_windows += 1;
                shadow_last = Some(s);
            }
            while let Some(d) = drift.next()? {
                let summary = DriftSummary::of(&d);
                above_live_line(live);
                match summary.outcome {
                    "diagnosing" => tracing::warn!(
                        event = "model_drift",
                        seq = d.sensor_seq,
                        "the machine drifts from its model: {} part, {} regime, residual ×{:.1}, {:.1} s into the run; diagnosing",
                        summary.part,
                        summary.regime,
                        summary.rms_ratio,
                        summary.detected_after_s
                    ),
                    _ => tracing::warn!(
                        event = "model_drift",
                        seq = d.sensor_seq,
                        "the drift detected {:.1} s into the run: {}",
                        summary.detected_after_s,
                        match &summary.effect {
                            Some(effect) => format!("{effect} {:?}", summary.params),
                            None => "no effect of the catalog names it".to_owned(),
                        }
                    ),
                }
                match drifts.iter_mut().find(|(seq, _)| *seq == d.sensor_seq) {
                    Some((_, known)) => *known = summary,
                    None => drifts.push((d.sensor_seq, summary)),
                }
            }
            let now = Instant::now();
            if now.saturating_duration_since(last_print) >= Duration::from_millis(500) {
                let rate =
                    (cycles - cycles_at_last_print) as f64 / now.saturating_duration_since(last_print).as_secs_f64();
                last_print = now;
                cycles_at_last_print = cycles;
                let line = LiveLine {
                    elapsed_s: now.saturating_duration_since(started).as_secs_f64(),
                    loop_hz: rate,
                    misses: late,
                    p99_us: by_stage[VALVE_STAGE].quantile_us(0.99),
                    last_second: tracking.last_second(),
                    since_start: tracking.since_start(),
                    restarts: processes.iter().map(|p| p.restarts).sum(),
                    on_simulation: machine_expected.then_some(on_simulation),
                    model_fit: config
                        .shadow
                        .model
                        .is_some()
                        .then(|| shadow_last.map_or(f64::NAN, |s| shadow_fit(&s))),
                }
                .render();
                if live {
                    eprint!("\r{line}");
                } else {
                    eprintln!("{line}");
                }
            }
            if cycles > 0 && end.is_none() {
                end = duration.map(|d| now + d);
            }
            Ok(if end.is_some_and(|end| now >= end) {
                Flow::Stop
            } else {
                Flow::Continue
            })
        };
        match step() {
            Ok(flow) => flow,
            Err(e) => {
                failure = Some(e);
                Flow::Stop
            }
        }
    })?;
    if live {
        eprintln!();
    }
    if let Some(e) = failure {
        return Err(e);
    }
    // A signal ends the run as the duration does: with a summary.
    let _: LoopExit = exit;
    Ok(RunSummary {
        duration_s: started.elapsed().as_secs_f64(),
        cycles,
        deadline_misses: late,
        latency_us: by_stage[VALVE_STAGE].summary(),
        latency_by_stage_us: STAGES
            .iter()
            .zip(&by_stage)
            .map(|(stage, h)| StageLatency {
                stage,
                from_reading: h.summary(),
            })
            .collect(),
        max_abs_tracking_error_rad: tracking.since_start().max_abs,
        rms_tracking_error_rad: tracking.since_start().rms,
        valve_fault_cycles: faults,
        valve_faults: valve_faults.faults,
        processes,
        faults: faults_seen,
        strangers,
        swaps,
        swap_failures,
        plant: if on_simulation { "simulation" } else { "machine" },
        plant_switches,
        recording: None,
        recorder: recorder_view,
        shadow: config.shadow.model.as_ref().map(|model| ShadowSummary {
            model: model.display().to_string(),
            windows: shadow_windows,
            fit_percent: shadow_last.map(|s| fit_percent(&s)).unwrap_or_default(),
            residual_pressures_pa: shadow_last.map(|s| s.residual_pressures).filter(|v| v.is_finite()),
            residual_angle_rad: shadow_last.map(|s| s.residual_angle).filter(|v| v.is_finite()),
            row_gaps: shadow_last.map_or(0, |s| s.row_gaps),
        }),
        model_drift: drifts.into_iter().map(|(_, d)| d).collect(),
        can: can_watch.map(|(port, stats, profile, _, _, wire_last)| {
            let f = stats.figures();
            CanSummary {
                bus: profile.interface.clone(),
                bitrate: profile.bitrate,
                load_percent: f.load_percent,
                frames_per_period: f.frames_per_period,
                late_pdos,
                lost_frames: f.lost_frames,
                malformed_pdos: f.malformed_pdos,
                // SocketCAN counts the controller's error frames itself.
                error_frames: f.error_frames.max(port.error_frames()),
                emcy: f.emcy,
                wire: wire_last.map(|w: hydractl_samples::WireStatus| WireSummary {
                    delivered: w.delivered,
                    lost: w.lost,
                    error_frames: w.error_frames,
                }),
            }
        }),
    })
}

/// On a terminal, ends the live line (redrawn in place) so that a log line
/// does not overwrite it.
fn above_live_line(live: bool) {
    if live {
        eprintln!();
    }
}

/// The recorder as it said itself: its last status, read live (a full
/// disk keeps it out of the file), and its restarts.
#[derive(Default, Clone, Copy)]
struct RecorderView {
    last: Option<hydractl_samples::RecorderStatus>,
    restarts: u32,
    /// The run's first reading, from which `not_recorded.from_s` counts.
    first_reading_ns: u64,
}

/// The recording's parts beside `out`: `STEM.mcap` or `STEM_NNN.mcap`,
/// and a restarted recorder's `STEM_restartN[_NNN].mcap`, in order.
fn recording_files(out: &Path) -> Result<Vec<PathBuf>> {
    let stem = out
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();
    let dir = out
        .parent()
        .filter(|d| !d.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    let is_part = |rest: &str| rest.len() == 3 && rest.bytes().all(|b| b.is_ascii_digit());
    let is_restart = |rest: &str| {
        rest.strip_prefix("restart").is_some_and(|r| {
            let (n, part) = r.split_once('_').unwrap_or((r, "000"));
            !n.is_empty() && n.bytes().all(|b| b.is_ascii_digit()) && is_part(part)
        })
    };
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .with_context(|| format!("listing {}", dir.display()))?
        .filter_map(Result::ok)
        .map(|e| e.path())
        .filter(|p| {
            let name = p
                .file_name()
                .map(|n| n.to_string_lossy().into_owned())
                .unwrap_or_default();
            name == format!("{stem}.mcap")
                || name
                    .strip_prefix(&format!("{stem}_"))
                    .and_then(|rest| rest.strip_suffix(".mcap"))
                    .is_some_and(|rest| is_part(rest) || is_restart(rest))
        })
        .collect();
    // The first recorder's parts, then each restart's.
    files.sort_by_key(|p| {
        let name = p.to_string_lossy().into_owned();
        (name.contains("_restart"), name)
    });
    Ok(files)
}

/// Reads back the files the recorder wrote, and says what is missing.
fn recording_report(out: &Path, recorder: RecorderView) -> Result<RecordingReport> {
    let mut report = RecordingReport {
        files: Vec::new(),
        messages: 0,
        channels: 0,
        dropped: 0,
        gaps: 0,
        complete: true,
        not_recorded: None,
        disk_full: 0,
        deleted_files: 0,
        recorder_restarts: recorder.restarts,
    };
    for file in recording_files(out)? {
        // A file a full disk or a killed recorder left unreadable is
        // reported, not fatal: the rest of the recording is still there.
        let summary = match hydractl_recording::summarize(&file) {
            Ok(summary) => summary,
            Err(e) => {
                tracing::warn!("{e}");
                report.complete = false;
                continue;
            }
        };
        report.messages += summary.messages;
        report.channels = report.channels.max(summary.channels.len());
        report.gaps += summary.channels.iter().map(|c| c.missing).sum::<u64>();
        report.files.push(file.display().to_string());
    }
    if let Some(last) = recorder.last {
        report.dropped = last.dropped;
        report.disk_full = last.disk_full;
        report.deleted_files = last.deleted_files;
        if last.unrecorded > 0 {
            report.not_recorded = Some(NotRecorded {
                samples: last.unrecorded,
                from_s: last.unrecorded_since_ns.saturating_sub(recorder.first_reading_ns) as f64 * 1e-9,
            });
        }
    }
    report.complete &= report.not_recorded.is_none() && recorder.restarts == 0 && recorder.last.is_some();
    Ok(report)
}

/// Whether a file can be written at `path`, without creating it: its
/// folder exists and takes a new file, and it is not itself a folder.
fn check_writable(path: &Path, flag: &str) -> Result<()> {
    if path.is_dir() {
        bail!("{flag} {}: is a folder, not a file", path.display());
    }
    let dir = path
        .parent()
        .filter(|d| !d.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    if !dir.is_dir() {
        bail!("{flag} {}: the folder {} does not exist", path.display(), dir.display());
    }
    let probe = dir.join(format!(".hydractl-write-check-{}", std::process::id()));
    std::fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .open(&probe)
        .with_context(|| format!("{flag} {}: cannot write in {}", path.display(), dir.display()))?;
    std::fs::remove_file(&probe).with_context(|| format!("removing {}", probe.display()))?;
    Ok(())
}

fn config_name(path: &Option<PathBuf>) -> String {
    path.as_ref()
        .map_or_else(|| "the built-in config".to_owned(), |p| p.display().to_string())
}

/// The machine on the virtual CAN bus: the bus's wire (`canbus`) and the
/// simulated ECUs (`ecus`), stopped in the reverse order when dropped.
struct VirtualMachine {
    children: Vec<(Child, &'static str)>,
}

impl VirtualMachine {
    fn start(scope: &RunScope, dir: &Path, config: Option<&Path>) -> Result<Self> {
        let mut machine = Self { children: Vec::new() };
        for name in ["canbus", "ecus"] {
            let mut command = Command::new(dir.join(name));
            if let Some(config) = config {
                command.arg("--config").arg(config);
            }
            let child = command
                .env(PREFIX_ENV, scope.prefix())
                .stdin(Stdio::null())
                .spawn()
                .with_context(|| format!("starting {}", dir.join(name).display()))?;
            machine.children.push((child, name));
            // The wire first: a frame sent before it listens is lost.
            let deadline = Instant::now() + Duration::from_secs(5);
            while !scope.live_node_names()?.iter().any(|n| n == name) {
                if let Some((child, _)) = machine.children.last_mut() {
                    if let Some(status) = child.try_wait()? {
                        bail!("{name} ended at start ({status})");
                    }
                }
                if Instant::now() >= deadline {
                    bail!("{name} did not open its node within 5 s");
                }
                std::thread::sleep(Duration::from_millis(5));
            }
        }
        Ok(machine)
    }
}

impl Drop for VirtualMachine {
    fn drop(&mut self) {
        for (child, name) in self.children.iter_mut().rev() {
            // Nothing is left to report to: the run's result is out.
            let _ = stop_child(child, name, Duration::from_secs(2));
        }
    }
}

/// SIGTERM, then SIGKILL if `child` has not stopped within `grace`.
pub(crate) fn stop_child(child: &mut Child, what: &str, grace: Duration) -> Result<()> {
    let _ = kill(Pid::from_raw(child.id() as i32), Signal::SIGTERM);
    let deadline = Instant::now() + grace;
    while Instant::now() < deadline {
        if child.try_wait()?.is_some() {
            return Ok(());
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    child.kill().with_context(|| format!("killing {what}"))?;
    child.wait()?;
    Ok(())
}
