//! What every process does at start-up: read its arguments and config,
//! quiet iceoryx2's logging, open its node in the run's scope.
//!
//! What it holds: One binary per process, each a line that calls its loop in
//! the library's `process` module (compiled once for all, not once per
//! binary): `plant`, `machine`, `sensor`, `friction`, `position`, `torque`,
//! `valve`, `supervisor`, `recorder`, `canbus` (the virtual CAN bus's wire:
//! `hydractl/can/<interface>/tx` in, arbitration and bus time by
//! `hydractl-can`'s `Wire`, `…/rx` out to every station), `shadow` (the model
//! beside the machine, `[shadow] model`: off the loop's CPU, reads the
//! readings and valve commands, publishes `hydractl/shadow` and
//! `hydractl/shadow/drift`, diagnoses a drift in a one-thread pool of its
//! own), `ecus` (the machine's CANopen nodes on the virtual bus:
//! `hydractl-can`'s simulated ECUs on the `[machine]` rotator, integrated in
//! real time between frames); a small library for start-up (`logging`: the
//! `tracing` subscriber of every process and of `hydractl`, text or the
//! systemd journal with its fields; locked memory before real time);
//! `supervisor`, the watchdog's whole logic, one file per concern (`child`:
//! spawning, reaping, back-off; `heartbeats`; `faults`: hang, spin (CPU time)
//! and blame judgements, how a limit-cycling controller comes back; `seat`:
//! the plant seat and its fallback; `swaps`: hot swaps (each judged by the
//! tracking error that follows, `tracking.rs`, and swapped back when it made
//! tracking worse), handovers, events, systemd's readiness and watchdog
//! (`service_manager.rs`, `sd-notify`); `valve_log`: judging a switch from
//! the valve's samples; `status`; `recorder`), each with unit tests, which
//! the `supervisor` binary only wires to its node and ticks; `live_plant`
//! (the paced plant loop shared by the simulated plant and the machine,
//! stand-in or on CAN), `can_sensors` (the machine's sensors on CAN: SYNC,
//! one period's PDOs until their deadline, heartbeats), `can_valve` (the
//! machine's valve on CAN: its guard verified by SDO, bring-up, set point,
//! every fault latched to disk until a person's reset, `valve_latch`),
//! `process/valve_desk.rs` (the valve's state published and `valve reset`
//! answered), `handover` (every handover read in order and acknowledged,
//! `HandoverInbox`; a controller's part in a hot swap: standby, exact
//! tracking, takeover at a named reading; and the plant seat, which of
//! machine and simulated plant publishes the readings), `recording` (taps
//! that drain services into a recording, republishers for replay), and
//! `shadow` (the shadow's rows joined from readings and valve commands, its
//! windows, its drift from alarm to named effect).

use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::Parser;
use hydractl_bus::{quiet_ipc_logging, Bus, RunScope};
use hydractl_config::Config;
use hydractl_samples::SensorSample;
use hydractl_stages::SensorEstimate;

mod can_sensors;
pub mod can_valve;
pub mod handover;
mod last_measured;
pub mod live_plant;
pub mod logging;
#[cfg(not(test))]
pub mod process;
pub mod recording;
pub mod shadow;
pub mod supervisor;
pub mod valve_latch;

#[derive(Parser, Debug)]
pub struct ProcessArgs {
    /// Configuration file [default: the built-in config/sim.toml].
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Plant only: resume from the loop's last reading,
    /// `SEQ,ANGLE_RAD,P_A_PA,P_B_PA[,VELOCITY_RAD_S]` (the supervisor passes
    /// it on a restart).
    #[arg(long, value_parser = parse_resume)]
    pub resume: Option<Resume>,
    #[command(flatten)]
    pub record: RecordArgs,
    /// Position and torque only: the controller variant, instead of the config's.
    #[arg(long)]
    pub variant: Option<String>,
    /// Position, torque and plants: start as a standby (a controller tracks
    /// the running one; the simulated plant watches the machine's state)
    /// until a handover makes it take over.
    #[arg(long)]
    pub standby: bool,
}

/// Recorder only: where and how to record.
#[derive(clap::Args, Debug, Clone, Default, PartialEq)]
pub struct RecordArgs {
    /// The MCAP file to write.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// With keep_mb: earlier runs' recordings beside `out` whose names
    /// start with `RING-` belong to the same ring, oldest deleted first.
    #[arg(long, hide = true, value_name = "RING")]
    pub ring: Option<String>,
    #[command(flatten)]
    pub split: SplitArgs,
}

/// How a recording is split into parts `STEM_000.mcap`, `STEM_001.mcap`, …:
/// the recorder's flags, and `hydractl run --record` and `hydractl record`,
/// which pass them on.
#[derive(clap::Args, Debug, Clone, Default, PartialEq)]
pub struct SplitArgs {
    /// Start a new file every this many MB.
    #[arg(long)]
    pub split_size_mb: Option<f64>,
    /// Start a new file every this many seconds.
    #[arg(long)]
    pub split_duration_s: Option<f64>,
    /// With a split: keep at most this many MB of parts, deleting the
    /// oldest as a flight recorder does [default: the config's
    /// `[recording] keep_mb`, else keep all].
    #[arg(long)]
    pub keep_mb: Option<f64>,
}

impl SplitArgs {
    pub fn splits(&self) -> bool {
        self.split_size_mb.is_some() || self.split_duration_s.is_some()
    }

    /// The recorder's arguments for writing to `out` with these splits;
    /// an error names a flag that is not a positive number.
    pub fn recorder_args(&self, out: &std::path::Path) -> Result<Vec<String>> {
        let mut args = vec!["--out".to_owned(), out.display().to_string()];
        if self.keep_mb.is_some() && !self.splits() {
            anyhow::bail!("--keep-mb needs a split to delete: --split-size-mb or --split-duration-s");
        }
        for (flag, value) in [
            ("--split-size-mb", self.split_size_mb),
            ("--split-duration-s", self.split_duration_s),
            ("--keep-mb", self.keep_mb),
        ] {
            if let Some(v) = value {
                if !(v.is_finite() && v > 0.0) {
                    anyhow::bail!("{flag} must be a positive number, got {v}");
                }
                args.extend([flag.to_owned(), v.to_string()]);
            }
        }
        Ok(args)
    }
}

/// Where a restarted plant resumes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Resume {
    pub seq: u64,
    pub angle: f64,
    pub p_a: f64,
    pub p_b: f64,
    /// The load's velocity, rad/s: a plant restarted at rest under a moving
    /// load would jolt it.
    pub velocity: f64,
}

impl Resume {
    pub fn to_arg(&self) -> String {
        format!(
            "{},{},{},{},{}",
            self.seq, self.angle, self.p_a, self.p_b, self.velocity
        )
    }
}

fn parse_resume(text: &str) -> Result<Resume, String> {
    let parts: Vec<&str> = text.split(',').collect();
    let (seq, angle, p_a, p_b, velocity) = match parts.as_slice() {
        [seq, angle, p_a, p_b] => (seq, angle, p_a, p_b, None),
        [seq, angle, p_a, p_b, velocity] => (seq, angle, p_a, p_b, Some(velocity)),
        _ => return Err(format!("`{text}` is not SEQ,ANGLE,P_A,P_B[,VELOCITY]")),
    };
    let number = |name: &str, v: &str| -> Result<f64, String> {
        v.trim()
            .parse::<f64>()
            .ok()
            .filter(|x| x.is_finite())
            .ok_or_else(|| format!("{name} `{v}` is not a finite number"))
    };
    Ok(Resume {
        seq: seq
            .trim()
            .parse()
            .map_err(|_| format!("SEQ `{seq}` is not a whole number"))?,
        angle: number("ANGLE", angle)?,
        p_a: number("P_A", p_a)?,
        p_b: number("P_B", p_b)?,
        velocity: velocity.map_or(Ok(0.0), |v| number("VELOCITY", v))?,
    })
}

pub struct Started {
    /// Every line this process logs names it and its pid.
    _log_span: tracing::span::EnteredSpan,
    pub name: String,
    pub config: Config,
    pub bus: Bus,
    pub args: ProcessArgs,
    pub injected: InjectedFault,
}

/// The environment variable through which a system test makes one process
/// misbehave: `PROCESS:spin@SEQ` makes `PROCESS` spin at the loop's
/// priority from reading `SEQ` on, as a controller stuck in a busy loop
/// would. Only a process that saw the readings before `SEQ` spins, so the
/// one restarted in its place does not.
pub(crate) const INJECT_FAULT_ENV: &str = "HYDRACTL_INJECT_FAULT";

/// A fault injected through `INJECT_FAULT_ENV`, if it names this process.
#[derive(Debug, Default)]
pub struct InjectedFault {
    spin_at: Option<u64>,
    saw_before: std::cell::Cell<bool>,
}

impl InjectedFault {
    fn for_process(name: &str, text: Option<&str>) -> Result<Self> {
        let Some(text) = text else {
            return Ok(Self::default());
        };
        let parsed = text.split_once(':').and_then(|(process, fault)| {
            let at = fault.strip_prefix("spin@")?.parse::<u64>().ok()?;
            Some((process, at))
        });
        let Some((process, at)) = parsed else {
            anyhow::bail!("{INJECT_FAULT_ENV}=`{text}` is not PROCESS:spin@SEQ");
        };
        Ok(Self {
            spin_at: (process == name).then_some(at),
            saw_before: std::cell::Cell::new(false),
        })
    }

    /// Called with every reading the process answers: from the injected
    /// one on, it never returns.
    pub(crate) fn at_reading(&self, seq: u64) {
        let Some(at) = self.spin_at else { return };
        if seq < at {
            self.saw_before.set(true);
        } else if self.saw_before.get() {
            loop {
                std::hint::spin_loop();
            }
        }
    }
}

impl Started {
    /// Raises a loop process to the configured real-time priority, once
    /// its start-up is done: at the loop's priority, a starting process
    /// (opening files, mapping memory) would hold the loop's CPU, and stall
    /// the running stages, for the whole of its start-up.
    pub fn enter_realtime(&self) {
        // Locked first: a page faulted in at the loop's priority would
        // stall the chain beside it.
        if self.config.timing.lock_memory {
            if let Err(e) = hydractl_rt::lock_memory() {
                tracing::warn!("{e}");
            }
        }
        // The valve, the last line of safety, one step above the chain: its
        // own clock runs even when a stage above it spins at the loop's
        // priority (SAFETY.md). Readings do not wake it, so it never takes
        // the CPU in the chain's middle: only a command, or its clock when
        // a command is overdue.
        let priority = self.config.timing.realtime_priority.map(|p| match self.name.as_str() {
            "valve" => (p + 1).min(99),
            _ => p,
        });
        if let Err(e) = hydractl_rt::run_realtime(priority) {
            tracing::warn!("{e}");
        }
    }
}

/// Parses the arguments, loads the config and opens the node `name`.
pub fn start(name: &str) -> Result<Started> {
    let args = ProcessArgs::parse();
    // Die with the parent (the supervisor, or `hydractl run` for the
    // supervisor): a killed parent must not leave the loop running.
    nix::sys::prctl::set_pdeathsig(nix::sys::signal::Signal::SIGTERM).context("setting the parent-death signal")?;
    // A child inherits its parent's signal mask, and the supervisor starts
    // a restart from inside its loop, where SIGINT and SIGTERM wait blocked:
    // unblocked here, every process hears them whoever started it.
    hydractl_bus::unblock_termination_signals().context("unblocking SIGINT and SIGTERM")?;
    let config = Config::load_or_default(args.config.as_deref())?;
    let filter = logging::filter(None, &config.log).map_err(anyhow::Error::msg)?;
    let log_span = logging::init(name, filter, &config.log);
    // The loop's CPU is for the loop: watching and writing files go elsewhere.
    let placed = if matches!(name, "supervisor" | "recorder" | "shadow") {
        hydractl_rt::keep_off_loop_cpu(config.timing.loop_cpu)
    } else {
        hydractl_rt::pin_to_loop_cpu(config.timing.loop_cpu)
    };
    if let Err(e) = placed {
        tracing::warn!("{e}");
    }
    quiet_ipc_logging();
    let scope = RunScope::from_env()?;
    let bus = Bus::open(&scope, name).with_context(|| format!("{name}: opening the bus"))?;
    let injected = InjectedFault::for_process(name, std::env::var(INJECT_FAULT_ENV).ok().as_deref())?;
    Ok(Started {
        _log_span: log_span,
        name: name.to_owned(),
        config,
        bus,
        args,
        injected,
    })
}

/// The trajectory's time for a sensor sequence number: the loop's own
/// clock, so that a restarted stage continues the same reference.
pub fn time_of(seq: u64, config: &Config) -> f64 {
    seq as f64 * config.timing.control_period()
}

/// The stages' view of a sensor sample.
pub fn estimate_of(s: &SensorSample) -> SensorEstimate {
    SensorEstimate {
        angle: s.angle,
        velocity: s.velocity,
        p_a: s.p_a,
        p_b: s.p_b,
        torque: s.torque,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn resume_round_trips_and_rejects_garbage() {
        let r = Resume {
            seq: 42,
            angle: -0.25,
            p_a: 8e6,
            p_b: 7.5e6,
            velocity: 0.3,
        };
        assert_eq!(parse_resume(&r.to_arg()), Ok(r));
        assert!(parse_resume("1,2,3").is_err());
        assert_eq!(
            parse_resume("1,0,0,0").map(|r| r.velocity),
            Ok(0.0),
            "at rest when not given"
        );
        assert!(parse_resume("x,0,0,0").is_err());
        assert!(parse_resume("1,NaN,0,0").is_err());
    }

    #[test]
    fn an_injected_fault_names_its_process_and_spares_a_restarted_one() {
        let none = InjectedFault::for_process("torque", None).expect("none");
        none.at_reading(5);
        let other = InjectedFault::for_process("torque", Some("position:spin@5")).expect("valid");
        other.at_reading(10);
        // Started past the reading, as a restarted process is: no spin.
        let restarted = InjectedFault::for_process("torque", Some("torque:spin@5")).expect("valid");
        restarted.at_reading(6);
        assert!(InjectedFault::for_process("torque", Some("torque:hang")).is_err());
    }
}
