//! What `hydractl run` reports: the summary's parts, as `--summary-json`
//! writes them (every field in tools/hydractl/README.md).

use std::collections::BTreeMap;

use hydractl_samples::name_str;

use super::recording::RecorderView;
use super::valve_faults;
use serde::Serialize;

#[derive(Serialize)]
pub(super) struct StageLatency {
    pub(super) stage: &'static str,
    pub(super) from_reading: LatencySummary,
}

#[derive(Serialize)]
pub(super) struct LatencySummary {
    pub(super) p50: f64,
    pub(super) p99: f64,
    pub(super) p999: f64,
    pub(super) max: f64,
}

#[derive(Serialize, Clone, Default)]
pub(super) struct ProcessSummary {
    pub(super) name: String,
    pub(super) pids: Vec<u32>,
    pub(super) restarts: u32,
    /// A loop process: page faults after it entered its loop, over all its
    /// pids (the goal is 0: its memory locked and touched before). Null
    /// for a process with no loop, or none that entered it.
    pub(super) page_faults_after_start: Option<u64>,
    /// A loop process: whether every one of its pids locked its memory.
    pub(super) memory_locked: Option<bool>,
    /// The newest count of each pid.
    #[serde(skip)]
    pub(super) faults_by_pid: Vec<(u32, u64, bool)>,
}

#[derive(Serialize)]
pub(super) struct RunSummary {
    pub(super) duration_s: f64,
    pub(super) cycles: u64,
    pub(super) deadline_misses: u64,
    /// Each stretch of misses with where its time went (the first 100).
    pub(super) deadline_miss_evidence: Vec<super::misses::MissEvidence>,
    /// Stretches of misses beyond those described.
    pub(super) deadline_miss_stretches_not_described: u64,
    /// Sensor reading to valve command, from the samples' own timestamps.
    pub(super) latency_us: LatencySummary,
    /// From the sensor reading to each stage's output, stage by stage along
    /// the chain: where the time goes.
    pub(super) latency_by_stage_us: Vec<StageLatency>,
    pub(super) max_abs_tracking_error_rad: f64,
    pub(super) rms_tracking_error_rad: f64,
    /// Readings whose angle was invalid (NaN: a sensor's value missing),
    /// left out of the tracking figures.
    pub(super) readings_without_angle: u64,
    /// Valve samples published in neutral with a fault flag.
    pub(super) valve_fault_cycles: u64,
    /// The same cycles by flag (`stale`, `not_finite`, `out_of_range`,
    /// `invalid_sensor`, `limit_cycle`, `device`): a cycle may have several.
    pub(super) valve_fault_cycles_by_kind: std::collections::BTreeMap<&'static str, u64>,
    /// The machine's valve's latched faults (CAN), each with its reset.
    pub(super) valve_faults: Vec<valve_faults::ValveFaultSummary>,
    pub(super) processes: Vec<ProcessSummary>,
    /// The longest time between two statuses of the supervisor (published
    /// every 100 ms): while it was silent, nothing watched the loop.
    pub(super) supervisor_longest_silence_ms: f64,
    /// Processes that crashed or hung, and how the stack recovered.
    pub(super) faults: Vec<FaultSummary>,
    /// Processes that are none of the run's and published on one of its
    /// services ([SAFETY.md](../../SAFETY.md), H10).
    pub(super) strangers: Vec<StrangerSummary>,
    /// Controller swaps while the run ran, as the supervisor judged them.
    pub(super) swaps: Vec<SwapSummary>,
    /// Swaps asked for that did not happen: the running controller stayed.
    pub(super) swap_failures: Vec<SwapSummary>,
    /// Each restart into a fallback variant, judged by the tracking after
    /// it: kept, fallen further back, or left down.
    pub(super) fallbacks_judged: Vec<FallbackJudgedSummary>,
    /// The plant the loop drove at the end: `machine` or `simulation`.
    pub(super) plant: &'static str,
    /// Each change of plant: the machine lost, or asked for.
    pub(super) plant_switches: Vec<PlantSwitchSummary>,
    /// What the recording holds, read back from its file(s) after the run.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub(super) recording: Option<RecordingReport>,
    /// The machine's CAN bus as a listener on it saw it.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub(super) can: Option<CanSummary>,
    /// The shadow model's last window, when `[shadow] model` is set.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub(super) shadow: Option<ShadowSummary>,
    /// Each drift of the machine from its model the shadow detected, with
    /// the effect its diagnosis named (none: not named, or not yet).
    pub(super) model_drift: Vec<DriftSummary>,
    #[serde(skip)]
    pub(super) recorder: RecorderView,
}

#[derive(Serialize)]
pub(super) struct ShadowSummary {
    pub(super) model: String,
    /// Windows compared.
    pub(super) windows: u64,
    /// The last window's fit per output, percent (`theta`, `p_a`, `p_b`).
    pub(super) fit_percent: BTreeMap<&'static str, f64>,
    /// The last window's residual RMS: pressures in Pa, angle in rad.
    pub(super) residual_pressures_pa: Option<f64>,
    pub(super) residual_angle_rad: Option<f64>,
    /// Times the shadow's rows started afresh (a reading it lost, a
    /// handover, a flagged reading).
    pub(super) row_gaps: u64,
}

#[derive(Serialize)]
pub(super) struct DriftSummary {
    pub(super) part: String,
    pub(super) regime: String,
    /// The machine's time at detection, s from the loop's first reading.
    pub(super) detected_after_s: f64,
    /// How much the part's residual grew, as a ratio of RMS.
    pub(super) rms_ratio: f64,
    /// The effect the diagnosis named, and its fitted parameters.
    pub(super) effect: Option<String>,
    pub(super) params: BTreeMap<String, f64>,
    /// `named`, `not named` (no effect of the catalog explains it) or
    /// `diagnosing` (the run ended first).
    pub(super) outcome: &'static str,
}

impl DriftSummary {
    pub(super) fn of(d: &hydractl_samples::ModelDrift) -> Self {
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
pub(super) struct CanSummary {
    /// The interface (`vcan0` on the virtual bus, `can0` on the vehicle).
    pub(super) bus: String,
    pub(super) bitrate: u32,
    /// Bus time of every frame, stuffing counted bit for bit, over the run.
    pub(super) load_percent: f64,
    /// Frames per SYNC.
    pub(super) frames_per_period: f64,
    /// A sensor value the machine did not have at `[can] pdo_deadline_us`
    /// after its SYNC: the reading went out with it missing (invalid).
    pub(super) late_pdos: u64,
    /// A period's TPDO that never came before the next SYNC.
    pub(super) lost_frames: u64,
    /// A period's TPDO of another length than its mapping's (refused).
    pub(super) malformed_pdos: u64,
    pub(super) error_frames: u64,
    pub(super) emcy: u64,
    /// The virtual bus's wire, by its own counters (null on SocketCAN):
    /// frames that crossed it and frames it lost (a full transmit queue,
    /// or handed over while bus-off).
    pub(super) wire: Option<WireSummary>,
}

#[derive(Serialize)]
pub(super) struct WireSummary {
    pub(super) delivered: u64,
    pub(super) lost: u64,
    pub(super) error_frames: u64,
    /// The wire's wake-ups that delivered a frame 0.1 ms or more after its
    /// last bit crossed, and the latest one came, µs: its timer runs on
    /// the loop's CPU at the loop's priority, so each is time that CPU was
    /// kept from the loop.
    pub(super) late_wakeups: u64,
    pub(super) late_worst_us: f64,
}

#[derive(Serialize)]
pub(super) struct RecordingReport {
    pub(super) files: Vec<String>,
    pub(super) messages: u64,
    pub(super) channels: usize,
    /// Samples the recorder lost by falling behind (its last status).
    pub(super) dropped: u64,
    /// Sequence numbers the publishers skipped themselves (a stage that took
    /// the newest reading): in the data, not lost by the recording.
    pub(super) gaps: u64,
    /// Everything the recorder received is in the files, and it never
    /// stopped: false makes the run exit 3.
    pub(super) complete: bool,
    /// What never reached a file: the disk was full.
    pub(super) not_recorded: Option<NotRecorded>,
    /// Times the disk was full.
    pub(super) disk_full: u32,
    /// Oldest parts deleted to keep within `keep_mb` (a ring, by design).
    pub(super) deleted_files: u32,
    /// Times the recorder itself was restarted: what it missed in between
    /// is not counted.
    pub(super) recorder_restarts: u32,
}

#[derive(Serialize, Clone, Copy, PartialEq)]
pub(super) struct NotRecorded {
    /// Samples received and not recorded.
    pub(super) samples: u64,
    /// The first of them, in seconds from the run's first reading.
    pub(super) from_s: f64,
}

#[derive(Serialize)]
pub(super) struct PlantSwitchSummary {
    pub(super) from: String,
    pub(super) to: String,
    /// `machine lost` or `asked`.
    pub(super) cause: &'static str,
    /// The first reading from the new plant.
    pub(super) at_seq: u64,
    /// For a lost machine: from its last reading to the switch.
    pub(super) detected_after_ms: f64,
}

impl FaultSummary {
    /// One line for the terminal: what happened, and how the loop came through it.
    pub(super) fn says(&self) -> String {
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
pub(super) struct StrangerSummary {
    pub(super) pid: u32,
    /// The service it published on, without the `hydractl/` in front.
    pub(super) service: String,
    /// The loop's newest reading when it was found.
    pub(super) at_seq: u64,
}

#[derive(Serialize)]
pub(super) struct FaultSummary {
    pub(super) process: String,
    /// `crash` (it exited), `hang` (no output while its input flowed),
    /// `misbehaving` (the valve rejected its commands as garbage, reading
    /// after reading), `limit_cycle` (the valve found its commands
    /// limit-cycling and held neutral) or `spin` (it took more than its
    /// share of the loop's CPU, starving the processes beside it).
    pub(super) kind: &'static str,
    pub(super) pid: u32,
    /// The last reading it answered.
    pub(super) last_seq: u64,
    /// From its last output to the supervisor seeing the fault.
    pub(super) detected_after_ms: f64,
    /// Readings from the last one it answered to the first with the valve
    /// made safe; null when the valve never had to be (it had nothing stale).
    pub(super) valve_safe_after_periods: Option<u64>,
    /// From the detection to the new process's first output; null when
    /// its restart rule left it down.
    pub(super) restarted_after_ms: Option<f64>,
    /// A misbehaving controller: the variant it was restarted into.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub(super) restarted_as: Option<String>,
    /// The tracking error's largest magnitude over the second after the
    /// fault's account arrived (its process back), rad: whether the
    /// restart shook the load. Null when the run ended before that second.
    pub(super) tracking_error_max_after_rad: Option<f64>,
}

#[derive(Serialize)]
pub(super) struct SwapSummary {
    pub(super) stage: String,
    pub(super) from: String,
    pub(super) to: String,
    /// The first sensor reading the new controller answered.
    pub(super) at_seq: u64,
    pub(super) missed_cycles: u64,
    /// The valve command's largest step from the switch through its
    /// transient (5 readings), as a fraction of its range.
    pub(super) command_step: f64,
    /// The loop's own largest steps: in the second before the switch, and
    /// in the second after its transient.
    pub(super) loop_step_before: f64,
    pub(super) loop_step_after: f64,
}

#[derive(Serialize)]
pub(super) struct FallbackJudgedSummary {
    pub(super) stage: String,
    /// The fallback variant judged.
    pub(super) variant: String,
    /// `kept`, `fell_back` (to `then_runs`) or `left_down` (the valve
    /// neutral until a person acts).
    pub(super) outcome: &'static str,
    pub(super) then_runs: Option<String>,
    /// The tracking error's rms before the fault, and over the judged
    /// window after the fallback settled.
    pub(super) tracking_rms_before_rad: f64,
    pub(super) tracking_rms_after_rad: f64,
    /// The loop's newest reading when it was judged.
    pub(super) at_seq: u64,
}

impl FallbackJudgedSummary {
    pub(super) fn of(e: &hydractl_samples::SupervisorEvent) -> Self {
        let (variant, to) = (name_str(&e.from).to_owned(), name_str(&e.to).to_owned());
        Self {
            stage: name_str(&e.process).to_owned(),
            outcome: match to.as_str() {
                "" => "left_down",
                same if same == variant => "kept",
                _ => "fell_back",
            },
            then_runs: Some(to).filter(|v| !v.is_empty()),
            variant,
            tracking_rms_before_rad: e.tracking_rms_before_rad,
            tracking_rms_after_rad: e.tracking_rms_after_rad,
            at_seq: e.sensor_seq,
        }
    }

    /// One line for the terminal.
    pub(super) fn says(&self) -> String {
        let figures = format!(
            "tracking {:.4} rad rms against {:.4} before the fault",
            self.tracking_rms_after_rad, self.tracking_rms_before_rad
        );
        match (self.outcome, &self.then_runs) {
            ("kept", _) => format!("{} keeps its fallback {}: {figures}", self.stage, self.variant),
            (_, Some(next)) => format!(
                "{}'s fallback {} fell back to {next}: {figures}",
                self.stage, self.variant
            ),
            _ => format!(
                "{}'s fallback {} left down, the valve neutral: {figures}",
                self.stage, self.variant
            ),
        }
    }
}
