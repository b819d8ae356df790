//! `hydractl swap`, `hydractl plant`, `hydractl valve` and `hydractl
//! status`: talking to a running stack.

use std::time::{Duration, Instant};

use anyhow::{bail, Result};
use hydractl_bus::{quiet_ipc_logging, Bus, CommandClient, Reader, RunScope, PREFIX_ENV};
use hydractl_samples::{
    code, name_str, service, source, RecorderStatus, ShadowSample, SupervisorReply, SupervisorRequest,
    SupervisorStatus, ValveDevice, ValveRequest, UNKNOWN,
};
use serde::Serialize;

#[derive(clap::Args)]
pub struct SwapArgs {
    /// `position` or `torque`.
    stage: String,
    /// position: `pid` or `mfc`; torque: `pid` or `hinf`.
    variant: String,
    /// Seconds to wait for the supervisor's answer.
    #[arg(long, default_value_t = 15.0)]
    timeout: f64,
}

#[derive(clap::Args)]
pub struct StatusArgs {
    /// Print JSON: {"running", "plant", "processes": [{"name", "pid", "variant", "healthy", "restarts"}],
    /// "valve": {"state", "latched_fault": {"code", "meaning"}, "since_s"}}; with no run alive,
    /// {"running": false} (and exit status 1).
    #[arg(long)]
    json: bool,
}

fn open_run(node: &str) -> Result<Bus> {
    quiet_ipc_logging();
    let scope = RunScope::from_env()?;
    if !scope.live_node_names()?.iter().any(|n| n == "supervisor") {
        bail!(
            "no run with prefix `{}` is alive: start one with `hydractl run` (or set {PREFIX_ENV})",
            scope.prefix()
        );
    }
    Ok(Bus::open(&scope, node)?)
}

/// Asks the supervisor to swap a controller while the loop runs, and waits
/// for the outcome.
pub fn swap(args: SwapArgs) -> Result<()> {
    let stage = match args.stage.as_str() {
        "position" => code::STAGE_POSITION,
        "torque" => code::STAGE_TORQUE,
        other => bail!("no stage `{other}`: swap `position` or `torque`"),
    };
    let Some(variant) = code::variant_code(&args.variant) else {
        bail!(
            "no variant `{}`: `pid`, `mfc` (position) or `hinf` (torque)",
            args.variant
        );
    };
    ask_supervisor("swap", SupervisorRequest { stage, variant }, args.timeout)
}

#[derive(clap::Args)]
pub struct PlantArgs {
    /// `sim`: run on the simulated plant; `machine`: back to the machine.
    to: String,
    /// Seconds to wait for the supervisor's answer.
    #[arg(long, default_value_t = 5.0)]
    timeout: f64,
}

/// Moves the loop to the simulated plant or back to the machine.
pub fn plant(args: PlantArgs) -> Result<()> {
    let variant = match args.to.as_str() {
        "sim" | "simulation" => source::SIMULATION,
        "machine" => source::MACHINE,
        other => bail!("no plant `{other}`: `sim` or `machine`"),
    };
    ask_supervisor(
        "plant",
        SupervisorRequest {
            stage: code::STAGE_PLANT,
            variant,
        },
        args.timeout,
    )
}

#[derive(clap::Args)]
pub struct ValveArgs {
    #[command(subcommand)]
    action: ValveAction,
}

#[derive(clap::Subcommand)]
enum ValveAction {
    /// Reset the machine's valve's latched fault: refused unless the loop asks
    /// neutral of the valve (or runs on the simulated plant); says what it reset.
    Reset {
        /// The valve was serviced: a valve that faulted again after each of
        /// the last resets needs this.
        #[arg(long)]
        serviced: bool,
        /// Seconds to wait for the valve process's answer.
        #[arg(long, default_value_t = 5.0)]
        timeout: f64,
    },
}

/// `hydractl valve reset`: a person's reset of the valve's latched fault.
pub fn valve(args: ValveArgs) -> Result<()> {
    match args.action {
        ValveAction::Reset { serviced, timeout } => ask(
            "valve reset",
            (service::VALVE_COMMAND, "the valve process (a run on CAN)"),
            ValveRequest {
                kind: code::VALVE_RESET,
                serviced: u32::from(serviced),
            },
            timeout,
        ),
    }
}

/// Sends `request` to the supervisor of the run and prints its answer; a
/// refusal is an error that says why.
fn ask_supervisor(what: &str, request: SupervisorRequest, timeout: f64) -> Result<()> {
    ask(what, (service::SUPERVISOR_COMMAND, "the supervisor"), request, timeout)
}

/// Sends `request` to the process serving `to` (its service, and who it is
/// in words) and prints its answer; a refusal is an error that says why.
fn ask<Req>(what: &str, to: (&str, &str), request: Req, timeout: f64) -> Result<()>
where
    Req: hydractl_bus::ZeroCopySend + std::fmt::Debug + Copy + 'static,
{
    let (service_name, who) = to;
    let bus = open_run(what)?;
    let client: CommandClient<Req, SupervisorReply> = CommandClient::open(&bus, service_name)?;
    let pending = client.send(request)?;
    if pending.servers() == 0 {
        bail!("{who} is not taking commands");
    }
    let deadline = Instant::now() + Duration::from_secs_f64(timeout.max(0.1));
    while Instant::now() < deadline {
        if let Some(answer) = pending.try_receive()? {
            let message = name_str(&answer.message);
            if answer.accepted == 0 {
                bail!("{what} refused: {message}");
            }
            return crate::emit(&format!("{message}\n"));
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    bail!("no answer from {who} within {timeout} s")
}

#[derive(Serialize)]
struct ProcessView {
    name: String,
    pid: u32,
    variant: Option<String>,
    healthy: bool,
    restarts: u32,
    /// A loop process: page faults since it answered its first reading.
    page_faults_after_start: Option<u32>,
    memory_locked: bool,
}

#[derive(Serialize)]
struct StatusView {
    running: bool,
    plant: &'static str,
    processes: Vec<ProcessView>,
    /// The run's recording, when it records.
    #[serde(skip_serializing_if = "Option::is_none")]
    recording: Option<RecordingView>,
    /// The shadow model's last window, when one watches the machine.
    #[serde(skip_serializing_if = "Option::is_none")]
    shadow: Option<ShadowView>,
    /// The machine's valve on CAN; null for the simulated valve.
    valve: Option<ValveView>,
}

#[derive(Serialize)]
struct ValveView {
    /// The device's state as its last status said ("active", "fault hold",
    /// "not heard").
    state: String,
    latched_fault: Option<LatchedFaultView>,
    /// How long the fault has been latched (across restarts), s.
    since_s: Option<f64>,
    /// Resets since the valve process started.
    resets: u32,
}

#[derive(Serialize)]
struct LatchedFaultView {
    code: u32,
    meaning: String,
}

/// The valve process's newest word on the machine's valve; `None` for a
/// run on the simulated valve (it publishes every 100 ms on CAN).
fn valve_view(device: &Reader<ValveDevice>) -> Result<Option<ValveView>> {
    let Some(d) = device.latest_within(Duration::from_millis(300))? else {
        return Ok(None);
    };
    let latched = d.latched != 0;
    Ok(Some(ValveView {
        state: name_str(&d.state).to_owned(),
        latched_fault: latched.then(|| LatchedFaultView {
            code: d.fault_code,
            meaning: name_str(&d.meaning).to_owned(),
        }),
        since_s: latched.then(|| (hydractl_bus::clock::unix_now_s() - d.latched_since_unix_ns as f64 * 1e-9).max(0.0)),
        resets: d.resets,
    }))
}

/// The shadow model's last word.
#[derive(Serialize)]
struct ShadowView {
    /// Windows compared so far.
    windows: u64,
    window_s: f64,
    /// Each output's fit over the last window, percent.
    fit_percent: std::collections::BTreeMap<&'static str, f64>,
    drift_alarms: u32,
    /// A drift's diagnosis is running.
    diagnosing: bool,
}

/// The shadow's newest window, when the run has a shadow.
fn shadow_view(shadow: &Reader<ShadowSample>, watched: bool) -> Result<Option<ShadowView>> {
    if !watched {
        return Ok(None);
    }
    // It publishes a window every `every_s` (1 s by default).
    let Some(sample) = shadow.latest_within(Duration::from_millis(1500))? else {
        return Ok(None);
    };
    Ok(Some(ShadowView {
        windows: sample.seq + 1,
        window_s: sample.window_s,
        fit_percent: crate::run::fit_percent(&sample),
        drift_alarms: sample.drift_alarms,
        diagnosing: sample.diagnosing != 0,
    }))
}

/// The recorder's last word.
#[derive(Serialize)]
struct RecordingView {
    messages: u64,
    bytes: u64,
    files: u32,
    /// Oldest parts deleted to stay within `keep_mb`.
    deleted_files: u32,
    /// Samples lost because the recorder fell behind.
    dropped: u64,
    /// Samples received and not recorded (a full disk): from when, how many.
    not_recorded: Option<NotRecordedView>,
}

#[derive(Serialize)]
struct NotRecordedView {
    samples: u64,
    /// For this long, up to now.
    for_last_s: f64,
}

/// The recorder's newest status, when the run records.
fn recording_view(recorder: &Reader<RecorderStatus>, records: bool) -> Result<Option<RecordingView>> {
    if !records {
        return Ok(None);
    }
    // It says itself every 100 ms.
    let Some(status) = recorder.latest_within(Duration::from_millis(300))? else {
        return Ok(None);
    };
    Ok(Some(RecordingView {
        messages: status.messages,
        bytes: status.bytes,
        files: status.files,
        deleted_files: status.deleted_files,
        dropped: status.dropped,
        not_recorded: (status.unrecorded > 0).then(|| NotRecordedView {
            samples: status.unrecorded,
            for_last_s: hydractl_bus::clock::now_ns().saturating_sub(status.unrecorded_since_ns) as f64 * 1e-9,
        }),
    }))
}

/// The supervisor's view of the running stack.
pub fn status(args: StatusArgs) -> Result<()> {
    let bus = match open_run("status") {
        Ok(bus) => bus,
        Err(e) => {
            if args.json {
                crate::emit("{\n  \"running\": false\n}\n")?;
            }
            return Err(e);
        }
    };
    let reader: Reader<SupervisorStatus> = Reader::open(&bus, service::SUPERVISOR_STATUS, 1)?;
    let recorder: Reader<RecorderStatus> = Reader::open(&bus, service::RECORDER_STATUS, 1)?;
    let shadow: Reader<ShadowSample> = Reader::open(&bus, service::SHADOW, 1)?;
    let device: Reader<ValveDevice> = Reader::open(&bus, service::VALVE_DEVICE, 1)?;
    let Some(status) = reader.latest_within(Duration::from_secs(2))? else {
        bail!("the supervisor published no status within 2 s");
    };
    let view = StatusView {
        running: true,
        plant: if status.plant_is_simulation != 0 {
            "simulation"
        } else {
            "machine"
        },
        processes: status.processes[..(status.process_count as usize).min(status.processes.len())]
            .iter()
            .map(|p| ProcessView {
                name: name_str(&p.name).to_owned(),
                pid: p.pid,
                variant: Some(name_str(&p.variant).to_owned()).filter(|v| !v.is_empty()),
                healthy: p.healthy != 0,
                restarts: p.restarts,
                page_faults_after_start: Some(p.page_faults_after_start).filter(|&n| n != UNKNOWN),
                memory_locked: p.memory_locked != 0,
            })
            .collect(),
        recording: recording_view(
            &recorder,
            status.processes.iter().any(|p| name_str(&p.name) == "recorder"),
        )?,
        shadow: shadow_view(&shadow, status.processes.iter().any(|p| name_str(&p.name) == "shadow"))?,
        valve: valve_view(&device)?,
    };
    if args.json {
        return crate::emit(&(serde_json::to_string_pretty(&view)? + "\n"));
    }
    // A machine in the run (in charge or in standby): the simulated plant
    // in charge is worth a warning. Without one it is simply the plant.
    let machine_expected = view.processes.iter().any(|p| p.name == "machine");
    let mut text = match view.plant {
        "simulation" if machine_expected => {
            "plant: SIMULATION (the loop drives the simulated plant, not the machine)\n".to_owned()
        }
        other => format!("plant: {other}\n"),
    };
    text += &format!(
        "  {:<12} {:>8} {:<10} {:<8} {:>8} {:>11}\n",
        "process", "pid", "variant", "health", "restarts", "page faults"
    );
    for p in &view.processes {
        let faults = p.page_faults_after_start.map_or("-".to_owned(), |n| {
            format!("{n}{}", if p.memory_locked { "" } else { " (unlocked)" })
        });
        text += &format!(
            "  {:<12} {:>8} {:<10} {:<8} {:>8} {:>11}\n",
            p.name,
            p.pid,
            p.variant.as_deref().unwrap_or("-"),
            if p.healthy { "healthy" } else { "DOWN" },
            p.restarts,
            faults
        );
    }
    if let Some(r) = &view.recording {
        text += &format!(
            "recording: {} messages, {:.1} MB in {} file(s){}, {} dropped\n",
            r.messages,
            r.bytes as f64 / 1e6,
            r.files,
            if r.deleted_files > 0 {
                format!(" ({} oldest deleted, keep_mb)", r.deleted_files)
            } else {
                String::new()
            },
            r.dropped
        );
        if let Some(n) = &r.not_recorded {
            text += &format!(
                "  NOT RECORDED: {} samples over the last {:.1} s (the disk is full)\n",
                n.samples, n.for_last_s
            );
        }
    }
    if let Some(v) = &view.valve {
        text += &match &v.latched_fault {
            Some(f) => format!(
                "valve: {}, FAULT LATCHED {:.0} s ago: {} ({}); neutral until `hydractl valve reset`\n",
                v.state,
                v.since_s.unwrap_or(0.0),
                hydractl_can::valve::fault_code_name(f.code),
                f.meaning
            ),
            None => format!("valve: {}\n", v.state),
        };
    }
    if let Some(s) = &view.shadow {
        let fits: Vec<String> = s.fit_percent.iter().map(|(o, f)| format!("{o} {f:.1} %")).collect();
        text += &format!(
            "shadow model: fit {} over the last {:.0} s ({} windows); {} drift alarm(s){}\n",
            if fits.is_empty() {
                "-".to_owned()
            } else {
                fits.join(", ")
            },
            s.window_s,
            s.windows,
            s.drift_alarms,
            if s.diagnosing { ", diagnosing one" } else { "" }
        );
    }
    crate::emit(&text)
}
