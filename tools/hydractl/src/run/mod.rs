//! `hydractl run`: starts the supervisor (which starts the loop), watches
//! the loop's samples, shows a live status, and writes the run's summary.

use std::collections::BTreeMap;
use std::io::IsTerminal;
use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use anyhow::{bail, Context, Result};
use hydractl_bus::{quiet_ipc_logging, run_loop, Bus, Flow, LoopExit, Reader, RunScope, PREFIX_ENV};
use hydractl_config::Config;
use hydractl_samples::service::STAGES;
use hydractl_samples::{
    service, FrictionSample, PlantReading, PositionSample, SensorSample, SupervisorEvent, SupervisorStatus, ValveSample,
};
use nix::sys::signal::{kill, Signal};
use nix::unistd::Pid;

mod events;
mod misses;
mod monitor;
mod recording;
mod summary;
mod valve_faults;
mod virtual_machine;

use events::EventsSeen;
use monitor::{merge_status, LatencyHistogram, LiveLine, SupervisorSilence, Tracking};
pub use recording::RecordingIncomplete;
use recording::{check_writable, recording_report, RecorderView};
use summary::*;
use virtual_machine::VirtualMachine;

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

/// The chain's last stage, the valve, among the stages that
/// `latency_by_stage_us` names in order.
const VALVE_STAGE: usize = STAGES.len() - 1;

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
            hydractl_canio::SocketCanPort::open(&can.interface, &[])
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
    if let Err(e) = hydractl_rt::keep_off_loop_cpu(config.timing.loop_cpu) {
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
    if let Some(line) = misses::report(&summary.deadline_miss_evidence) {
        eprintln!("{line}");
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
    if summary.readings_without_angle > 0 {
        crate::emit(&format!(
            "{} readings had no valid angle (a sensor's value missing) and are not in the tracking figures\n",
            summary.readings_without_angle
        ))?;
    }
    match &summary.recording {
        Some(r) if !r.complete => Err(RecordingIncomplete(r.what_is_missing()).into()),
        _ => Ok(()),
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
    let mut faults_by_kind = std::collections::BTreeMap::new();
    let mut late = 0u64;
    let mut misses = misses::Misses::new(
        hydractl_bus::clock::now_ns(),
        (config.timing.control_period() * 1e9) as u64,
    );
    let mut last_valve_seq: Option<u64> = None;
    let mut processes: Vec<ProcessSummary> = vec![ProcessSummary {
        name: "supervisor".into(),
        pids: vec![supervisor_pid],
        ..ProcessSummary::default()
    }];
    let mut last_print = Instant::now();
    let mut cycles_at_last_print = 0u64;
    let mut seen = EventsSeen::default();
    let mut supervisor_silence = SupervisorSilence::default();
    // Readings the tracking could not judge: their angle was invalid.
    let mut readings_without_angle = 0u64;
    let per_second = config.timing.control_rate_hz.round() as u64;
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
            let port = hydractl_canio::open_monitor(&bus, &profile)?;
            // Every reading, for the machine's PDOs that were not there in time.
            let readings: Reader<PlantReading> = Reader::open(&bus, service::PLANT_READING, 256)?;
            let wire: Reader<hydractl_samples::WireStatus> =
                Reader::open(&bus, &service::can_wire(&profile.interface), 64)?;
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
                    misses.on_wire(w.late_max_due_ns, w.late_max_ns);
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
                        misses.stamp(VALVE_STAGE, v.sensor_seq, v.sensor_time_ns, v.stage_time_ns);
                    }
                }
                if v.faults != 0 {
                    faults += 1;
                    for (flag, name) in hydractl_samples::fault::NAMES {
                        if v.faults & flag != 0 {
                            *faults_by_kind.entry(name).or_insert(0) += 1;
                        }
                    }
                }
            }
            while let Some(x) = sensor.next()? {
                by_stage[0].record_between(x.sensor_time_ns, x.stage_time_ns);
                misses.stamp(0, x.sensor_seq, x.sensor_time_ns, x.stage_time_ns);
            }
            while let Some(x) = friction.next()? {
                by_stage[1].record_between(x.sensor_time_ns, x.stage_time_ns);
                misses.stamp(1, x.sensor_seq, x.sensor_time_ns, x.stage_time_ns);
            }
            while let Some(p) = position.next()? {
                by_stage[2].record_between(p.sensor_time_ns, p.stage_time_ns);
                misses.stamp(2, p.sensor_seq, p.sensor_time_ns, p.stage_time_ns);
                let e = p.reference_angle - p.angle;
                // An invalid reading (a PDO that did not come) has no angle:
                // the valve was neutral for it, and the next one counts.
                if e.is_finite() {
                    tracking.push(e);
                } else {
                    readings_without_angle += 1;
                }
                seen.on_tracking(&tracking, per_second);
            }
            if let Some(p) = plant.latest()? {
                late_by_source[usize::from(p.source == hydractl_samples::source::MACHINE)] = p.late_commands;
                late = late_by_source.iter().sum();
            }
            while let Some(t) = torque.next()? {
                by_stage[3].record_between(t.sensor_time_ns, t.stage_time_ns);
                misses.stamp(3, t.sensor_seq, t.sensor_time_ns, t.stage_time_ns);
            }
            let now_ns = hydractl_bus::clock::now_ns();
            misses.on_late(late, now_ns);
            misses.tick(now_ns);
            if let Some(s) = status.latest()? {
                merge_status(&mut processes, &s);
                on_simulation = s.plant_is_simulation != 0;
                supervisor_silence.status(s.stage_time_ns, now_ns);
            }
            if let Some(silent_ns) = supervisor_silence.check(now_ns) {
                above_live_line(live);
                tracing::warn!(
                    "the supervisor has published no status for {} ms: its rounds (restarts, the fault account, swaps) have stopped, and the loop runs on unwatched",
                    silent_ns / 1_000_000
                );
            }
            while let Some(e) = events.next()? {
                seen.take(&e, live, tracking.count());
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
    let (deadline_miss_evidence, deadline_miss_stretches_not_described) = misses.finish();
    Ok(RunSummary {
        duration_s: started.elapsed().as_secs_f64(),
        cycles,
        deadline_misses: late,
        deadline_miss_evidence,
        deadline_miss_stretches_not_described,
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
        readings_without_angle,
        supervisor_longest_silence_ms: supervisor_silence.longest_ns as f64 * 1e-6,
        valve_fault_cycles: faults,
        valve_fault_cycles_by_kind: faults_by_kind,
        valve_faults: valve_faults.faults,
        processes,
        faults: seen.faults,
        strangers: seen.strangers,
        swaps: seen.swaps,
        swap_failures: seen.swap_failures,
        fallbacks_judged: seen.fallbacks_judged,
        plant: if on_simulation { "simulation" } else { "machine" },
        plant_switches: seen.plant_switches,
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
                    late_wakeups: w.late_wakeups,
                    late_worst_us: w.late_worst_ns as f64 * 1e-3,
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

fn config_name(path: &Option<PathBuf>) -> String {
    path.as_ref()
        .map_or_else(|| "the built-in config".to_owned(), |p| p.display().to_string())
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
